#include "server/assets/asset_refs.hpp"

#include <fmt/format.h>

#include <cstring>
#include <fstream>
#include <set>
#include <stdexcept>

#include "common/lighting/asset_resolver.hpp"
#include "common/spec/spec_reader.hpp"

namespace tally {

namespace {

void walk(const nlohmann::json& j, const std::string& pointer, std::vector<AssetRef>& out) {
  if (j.is_string()) {
    if (auto hex = asset_ref_hex(j.get_ref<const std::string&>())) out.push_back({pointer, *hex});
  } else if (j.is_object()) {
    for (const auto& [k, v] : j.items()) walk(v, json_pointer_append(pointer, k), out);
  } else if (j.is_array()) {
    for (size_t i = 0; i < j.size(); ++i) walk(j[i], json_pointer_append(pointer, i), out);
  }
}

// A URI as tinygltf reads it before it asks for the file (tiny_gltf.h, dlib::urldecode):
// "%XX" is the byte XX, "+" a space.
std::string uri_decoded(std::string_view s) {
  auto nibble = [](char c) -> int {
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return 0;
  };
  std::string out;
  for (size_t i = 0; i < s.size(); ++i) {
    if (s[i] == '+') {
      out += ' ';
    } else if (s[i] == '%' && i + 2 < s.size()) {
      out += static_cast<char>((nibble(s[i + 1]) << 4) | nibble(s[i + 2]));
      i += 2;
    } else {
      out += s[i];
    }
  }
  return out;
}

// Every string of a JSON text, unescaped (nlohmann's SAX parser: no recursion, no
// document kept) and URI-decoded: the names a glTF loader resolves, however written.
struct JsonStringRefs : nlohmann::json_sax<nlohmann::json> {
  std::vector<std::string>* out;
  explicit JsonStringRefs(std::vector<std::string>* o) : out(o) {}
  bool string(string_t& v) override {
    if (auto hex = asset_ref_hex(uri_decoded(v))) out->push_back(*hex);
    return true;
  }
  bool null() override { return true; }
  bool boolean(bool) override { return true; }
  bool number_integer(number_integer_t) override { return true; }
  bool number_unsigned(number_unsigned_t) override { return true; }
  bool number_float(number_float_t, const string_t&) override { return true; }
  bool binary(binary_t&) override { return true; }
  bool start_object(std::size_t) override { return true; }
  bool key(string_t&) override { return true; }
  bool end_object() override { return true; }
  bool start_array(std::size_t) override { return true; }
  bool end_array() override { return true; }
  bool parse_error(std::size_t, const std::string&, const nlohmann::detail::exception&) override { return false; }
};

// The names in the JSON of a glTF file: the whole file when it starts with '{', the
// JSON chunk of a .glb (magic "glTF", the chunk from byte 20). Other files name none here.
void json_refs(const std::filesystem::path& file, std::vector<std::string>& out) {
  std::ifstream in(file, std::ios::binary);
  char head[20] = {};
  in.read(head, sizeof head);
  const auto got = static_cast<size_t>(in.gcount());
  size_t start = 0;
  if (got == sizeof head && std::memcmp(head, "glTF", 4) == 0 && std::memcmp(head + 16, "JSON", 4) == 0) {
    start = 20;
  } else {
    while (start < got && std::strchr(" \t\r\n", head[start]) != nullptr) ++start;
    if (start == got || head[start] != '{') return;
  }
  in.clear();
  in.seekg(static_cast<std::streamoff>(start));
  JsonStringRefs sax(&out);
  // Not strict: a .glb's binary chunk follows its JSON.
  nlohmann::json::sax_parse(in, &sax, nlohmann::json::input_format_t::json, false);
}

}  // namespace

std::vector<std::string> asset_refs_in_file(const std::filesystem::path& file) {
  std::ifstream in(file, std::ios::binary);
  if (!in) throw std::runtime_error(fmt::format("cannot read {}", file.string()));
  std::vector<std::string> out;
  // A glTF's JSON may write a name with escapes ("sha256\u003a…") or percent-encoding
  // ("sha256%3A…") that the loader undoes: the parsed strings, besides the bytes below.
  json_refs(file, out);
  constexpr size_t kRef = kAssetRefPrefix.size() + 64;
  std::string window;  // the last kRef - 1 bytes of the previous part, then the next part
  std::vector<char> part(size_t{1} << 20);
  while (in) {
    in.read(part.data(), static_cast<std::streamsize>(part.size()));
    window.append(part.data(), static_cast<size_t>(in.gcount()));
    for (size_t at = window.find(kAssetRefPrefix); at != std::string::npos && at + kRef <= window.size();
         at = window.find(kAssetRefPrefix, at + 1)) {
      if (auto hex = asset_ref_hex(std::string_view(window).substr(at, kRef))) out.push_back(*hex);
    }
    if (window.size() >= kRef) window.erase(0, window.size() - (kRef - 1));
  }
  if (in.bad()) throw std::runtime_error(fmt::format("cannot read {}", file.string()));
  return out;
}

std::vector<AssetRef> asset_refs(const nlohmann::json& spec) {
  std::vector<AssetRef> out;
  walk(spec, "", out);
  return out;
}

}  // namespace tally
