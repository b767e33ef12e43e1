#include "common/spec/json_depth.hpp"

#include "common/spec/json_value_sax.hpp"
#include <vector>

namespace tally {

namespace {

// SAX handler that keeps the path to the value being parsed.
class PathTracker : public JsonValueSax {
 public:
  std::string pointer() const {
    std::string out;
    for (const Level& l : path_) {
      out.push_back('/');
      if (!l.object) {
        out += std::to_string(l.index);
        continue;
      }
      for (char c : l.key) {
        if (c == '~') {
          out += "~0";
        } else if (c == '/') {
          out += "~1";
        } else {
          out.push_back(c);
        }
      }
    }
    return out;
  }

  bool start_object(std::size_t) override {
    enter(true);
    return true;
  }
  bool key(string_t& k) override {
    path_.back().key = k;
    return true;
  }
  bool end_object() override { return leave(); }
  bool start_array(std::size_t) override {
    enter(false);
    return true;
  }
  bool end_array() override { return leave(); }

 private:
  struct Level {
    bool object;
    std::string key;
    size_t index = 0;
  };
  // A value in an array advances the index; the pointer of a value being parsed is
  // the index it will get.
  bool value() override {
    if (!path_.empty() && !path_.back().object) path_.back().index++;
    return true;
  }
  void enter(bool object) { path_.push_back(Level{object, {}, 0}); }
  bool leave() {
    path_.pop_back();
    return value();
  }
  std::vector<Level> path_;
};

}  // namespace

std::string json_pointer_at_error(std::string_view text) {
  PathTracker t;
  nlohmann::json::sax_parse(text, &t);
  return t.pointer();
}

size_t json_nesting_depth(std::string_view text, size_t limit) {
  size_t depth = 0, deepest = 0;
  bool in_string = false, escaped = false;
  for (char c : text) {
    if (in_string) {
      if (escaped) {
        escaped = false;
      } else if (c == '\\') {
        escaped = true;
      } else if (c == '"') {
        in_string = false;
      }
      continue;
    }
    switch (c) {
      case '"': in_string = true; break;
      case '[':
      case '{':
        if (++depth > deepest) {
          deepest = depth;
          if (deepest > limit) return limit + 1;
        }
        break;
      case ']':
      case '}':
        if (depth > 0) --depth;
        break;
      default: break;
    }
  }
  return deepest;
}

}  // namespace tally
