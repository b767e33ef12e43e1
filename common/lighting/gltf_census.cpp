#include "common/lighting/gltf_census.hpp"

#include "common/spec/json_value_sax.hpp"

#include <cstring>
#include <vector>

namespace tally {

namespace {

class Counter : public JsonValueSax {
 public:
  explicit Counter(GltfCensus& out) : out_(out) {}

  bool start_object(std::size_t) override {
    value();
    path_.push_back(Frame{true, {}});
    return true;
  }
  bool key(string_t& k) override {
    // Only the keys counting depends on are kept (top level, and "primitives" in a mesh).
    if (path_.size() == 1 || (path_.size() == 3 && k == "primitives")) {
      path_.back().key = k;
    } else {
      path_.back().key.clear();
    }
    return true;
  }
  bool end_object() override {
    path_.pop_back();
    return true;
  }
  bool start_array(std::size_t) override {
    value();
    path_.push_back(Frame{false, {}});
    return true;
  }
  bool end_array() override {
    path_.pop_back();
    return true;
  }

 private:
  struct Frame {
    bool object;
    std::string key;
  };
  // A value (or the start of a container) inside the innermost frame.
  bool value() override {
    const size_t n = path_.size();
    if (n == 2 && path_[0].object && !path_[1].object && !path_[0].key.empty()) out_.arrays[path_[0].key]++;
    if (n == 4 && path_[0].key == "meshes" && !path_[1].object && path_[2].object && path_[2].key == "primitives" &&
        !path_[3].object) {
      out_.primitives++;
    }
    return true;
  }
  GltfCensus& out_;
  std::vector<Frame> path_;
};

uint32_t le32(std::string_view b, size_t at) {
  uint32_t v;
  std::memcpy(&v, b.data() + at, 4);
  return v;  // glTF is little-endian, as every machine tally builds for
}

}  // namespace

std::optional<std::string_view> glb_json_chunk(std::string_view glb) {
  // Header: "glTF", version, total length; then the first chunk: length, "JSON", data.
  if (glb.size() < 20 || glb.compare(0, 4, "glTF") != 0 || glb.compare(16, 4, "JSON") != 0) return std::nullopt;
  const uint32_t len = le32(glb, 12);
  if (len > glb.size() - 20) return std::nullopt;
  return glb.substr(20, len);
}

bool glb_chunks_fit(std::string_view glb) {
  const std::optional<std::string_view> json = glb_json_chunk(glb);
  if (!json) return false;
  size_t at = 20 + json->size();
  while (at < glb.size()) {
    if (glb.size() - at < 8) return false;  // a chunk header cut off
    const uint32_t len = le32(glb, at);
    if (len > glb.size() - at - 8) return false;  // its data runs past the end
    at += 8 + static_cast<size_t>(len);
  }
  return true;
}

GltfCensus gltf_census(std::string_view json) {
  GltfCensus out;
  Counter c(out);
  nlohmann::json::sax_parse(json, &c, nlohmann::json::input_format_t::json, false);
  return out;
}

}  // namespace tally
