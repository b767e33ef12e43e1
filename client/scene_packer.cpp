#include "client/scene_packer.hpp"

#include <fmt/format.h>
#include <sys/stat.h>

#include <cerrno>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <memory>
#include <sstream>
#include <vector>

#include "client/json_errors.hpp"
#include "common/hash/digest.hpp"
#include "common/lighting/asset_resolver.hpp"

namespace tally {

namespace fs = std::filesystem;
using nlohmann::json;

namespace {

std::string shown(const fs::path& p) { return p.lexically_normal().string(); }

// Why `path` cannot be read as a file: "No such file or directory", "is a directory", ...
std::string unreadable_reason(const fs::path& path) {
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0) return std::strerror(errno);
  if (!S_ISREG(st.st_mode)) return "is not a regular file";
  return "";
}

std::string read_file(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    const std::string why = unreadable_reason(path);
    throw PackError(fmt::format("cannot read {}: {}", shown(path), why.empty() ? std::strerror(errno) : why));
  }
  std::ostringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

// glTF URIs are percent-encoded; tinygltf decodes them the same way (dlib's urldecode).
std::string uri_decode(const std::string& s) {
  auto hex = [](char c) -> int {
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return -1;
  };
  std::string out;
  for (size_t i = 0; i < s.size(); ++i) {
    if (s[i] == '%' && i + 2 < s.size() && hex(s[i + 1]) >= 0 && hex(s[i + 2]) >= 0) {
      out.push_back(static_cast<char>(hex(s[i + 1]) * 16 + hex(s[i + 2])));
      i += 2;
    } else if (s[i] == '+') {
      out.push_back(' ');
    } else {
      out.push_back(s[i]);
    }
  }
  return out;
}

uint32_t u32_at(const std::string& b, size_t off) {
  uint32_t x = 0;
  std::memcpy(&x, b.data() + off, 4);
  return x;  // glTF is little-endian, as every machine tally builds on
}
void append_u32(std::string& b, uint32_t x) { b.append(reinterpret_cast<const char*>(&x), 4); }

constexpr uint32_t kGlbMagic = 0x46546C67u;  // "glTF"
constexpr uint32_t kJsonChunk = 0x4E4F534Au;  // "JSON"

// Lines of `text` (the '\n' kept with each) with `fix` applied to each line.
template <class F>
std::string map_lines(const std::string& text, F&& fix) {
  std::string out;
  size_t pos = 0;
  while (pos < text.size()) {
    size_t end = text.find('\n', pos);
    const bool nl = end != std::string::npos;
    if (!nl) end = text.size();
    out += fix(text.substr(pos, end - pos));
    if (nl) out += '\n';
    pos = end + 1;
  }
  return out;
}

std::vector<std::string> words(const std::string& line) {
  std::vector<std::string> out;
  std::istringstream in(line);
  for (std::string w; in >> w;) out.push_back(w);
  return out;
}

}  // namespace

std::string sha256_file_hex(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw PackError(fmt::format("cannot read {}: {}", shown(path), std::strerror(errno)));
  try {
    Sha256 h;  // common/hash/digest.hpp
    std::vector<char> buf(1 << 20);
    while (in) {
      in.read(buf.data(), static_cast<std::streamsize>(buf.size()));
      h.update(std::string_view(buf.data(), static_cast<size_t>(in.gcount())));
    }
    if (in.bad()) throw PackError(fmt::format("cannot read {}: {}", shown(path), std::strerror(errno)));
    return h.finish_hex();
  } catch (const DigestError& e) {
    throw PackError(e.what());
  }
}

std::string sha256_bytes_hex(const std::string& bytes) {
  try {
    return sha256_hex(bytes);
  } catch (const DigestError& e) {
    throw PackError(e.what());
  }
}

void ScenePacker::pack_spec(json& j) {
  if (j.is_object()) {
    // A mesh with its own "material" has its OBJ's mtllib ignored by the server (so not packed).
    const bool own_material = j.contains("material");
    for (auto& [k, v] : j.items()) {
      if (is_scene_file_field(k) && v.is_string() && !looks_like_asset_ref(v.get<std::string>())) {
        const fs::path name(v.get<std::string>());
        const fs::path local = name.is_absolute() ? name : base_ / name;
        std::error_code ec;
        if (!fs::is_regular_file(local, ec)) continue;  // not ours: the server's --asset-dir may have it
        const Format f = k == "file" ? Format::gltf : k == "obj" && !own_material ? Format::obj : Format::plain;
        v = pack(local, f);
      } else {
        pack_spec(v);
      }
    }
  } else if (j.is_array()) {
    for (auto& v : j) pack_spec(v);
  }
}

std::string ScenePacker::pack(const fs::path& path, Format format) {
  std::error_code ec;
  const fs::path canon = fs::weakly_canonical(path, ec);
  const std::string key = (ec ? fs::absolute(path) : canon).string() + "|" + std::to_string(static_cast<int>(format));
  if (auto it = done_.find(key); it != done_.end()) return it->second;
  if (depth_ > 4) throw PackError(fmt::format("{}: files name each other too deeply (a cycle?)", shown(path)));
  ++depth_;
  std::string ref;
  try {
    switch (format) {
      case Format::gltf: ref = pack_gltf(path); break;
      case Format::obj: ref = pack_obj(path); break;
      case Format::mtl: ref = pack_mtl(path, obj_dir_); break;
      case Format::plain:
        ref = std::string(kAssetRefPrefix) + sha256_file_hex(path);
        store_.put_file(ref, path);
        break;
    }
  } catch (...) {
    --depth_;
    throw;
  }
  --depth_;
  origins_.emplace(ref, shown(path));
  done_.emplace(key, ref);
  return ref;
}

std::string ScenePacker::store_packed(const fs::path& path, const std::string& original, const std::string* rewritten) {
  if (rewritten) return store_bytes(*rewritten, path);
  const std::string ref = std::string(kAssetRefPrefix) + sha256_bytes_hex(original);
  store_.put_file(ref, path);  // unchanged: sent from disk as it is
  return ref;
}

std::string ScenePacker::store_bytes(const std::string& bytes, const fs::path& origin) {
  const std::string ref = std::string(kAssetRefPrefix) + sha256_bytes_hex(bytes);
  store_.put_bytes(ref, bytes, origin);
  return ref;
}

std::string ScenePacker::nested(const fs::path& referrer, const char* format, const std::string& what,
                                const std::string& name, const fs::path& dir, Format kind) {
  if (looks_like_asset_ref(name)) return name;  // already a store name
  const fs::path local = fs::path(name).is_absolute() ? fs::path(name) : dir / name;
  const std::string why = unreadable_reason(local);
  if (!why.empty()) {
    throw PackError(fmt::format("{} ({}): {} names \"{}\", which cannot be read ({}: {})", shown(referrer), format, what,
                                name, shown(local), why));
  }
  return pack(local, kind);
}

std::string ScenePacker::pack_gltf(const fs::path& path) {
  const std::string bytes = read_file(path);
  const bool glb = bytes.size() >= 4 && u32_at(bytes, 0) == kGlbMagic;
  std::string text;
  size_t json_end = 0;  // GLB: where the JSON chunk ends (the BIN chunk follows)
  if (glb) {
    if (bytes.size() < 20 || u32_at(bytes, 16) != kJsonChunk || 20 + size_t{u32_at(bytes, 12)} > bytes.size()) {
      throw PackError(fmt::format("{} (glTF binary): the file is cut short or its first chunk is not JSON", shown(path)));
    }
    json_end = 20 + size_t{u32_at(bytes, 12)};
    text = bytes.substr(20, json_end - 20);
  }
  const std::string& doc_text = glb ? text : bytes;
  json doc;
  try {
    doc = json::parse(doc_text);
  } catch (const json::parse_error& e) {
    throw PackError(fmt::format("{} ({}): not valid JSON: {}", shown(path), glb ? "glTF binary" : "glTF",
                                json_parse_error_text(e)));
  }
  if (!doc.is_object()) throw PackError(fmt::format("{} (glTF): not a glTF document (not a JSON object)", shown(path)));
  const fs::path dir = path.parent_path();
  bool changed = false;
  for (const char* list : {"buffers", "images"}) {
    if (!doc.contains(list) || !doc[list].is_array()) continue;
    for (size_t i = 0; i < doc[list].size(); ++i) {
      json& item = doc[list][i];
      if (!item.is_object() || !item.contains("uri") || !item["uri"].is_string()) continue;
      const std::string uri = item["uri"].get<std::string>();
      if (uri.rfind("data:", 0) == 0 || looks_like_asset_ref(uri)) continue;
      item["uri"] = nested(path, glb ? "glTF binary" : "glTF", fmt::format("{}[{}]", list, i), uri_decode(uri), dir,
                           Format::plain);
      changed = true;
    }
  }
  if (!changed) return store_packed(path, bytes, nullptr);
  if (!glb) return store_bytes(doc.dump(), path);
  std::string js = doc.dump();
  while (js.size() % 4 != 0) js.push_back(' ');
  const std::string rest = bytes.substr(json_end);
  std::string out;
  append_u32(out, kGlbMagic);
  append_u32(out, u32_at(bytes, 4));  // version
  append_u32(out, static_cast<uint32_t>(12 + 8 + js.size() + rest.size()));
  append_u32(out, static_cast<uint32_t>(js.size()));
  append_u32(out, kJsonChunk);
  out += js;
  out += rest;
  return store_bytes(out, path);
}

std::string ScenePacker::pack_obj(const fs::path& path) {
  const std::string text = read_file(path);
  const fs::path dir = path.parent_path();
  obj_dir_ = dir;
  bool changed = false;
  const std::string out = map_lines(text, [&](const std::string& line) {
    const std::vector<std::string> w = words(line);
    if (w.empty() || w[0] != "mtllib") return line;
    std::string fixed = "mtllib";
    for (size_t i = 1; i < w.size(); ++i) {
      fixed += " " + nested(path, "OBJ", "mtllib", w[i], dir, Format::mtl);
    }
    changed = true;
    return fixed;
  });
  return store_packed(path, text, changed ? &out : nullptr);
}

// The server reads an .mtl's map_Kd textures (common/lighting: mtl_texture); other maps
// are parsed and never opened, so they are left as they are. A texture is looked for
// next to the .mtl, then next to the OBJ (where the server looks when both sit together).
std::string ScenePacker::pack_mtl(const fs::path& path, const fs::path& obj_dir) {
  const std::string text = read_file(path);
  const fs::path dir = path.parent_path();
  bool changed = false;
  const std::string out = map_lines(text, [&](const std::string& line) {
    const std::vector<std::string> w = words(line);
    if (w.size() < 2 || w[0] != "map_Kd") return line;
    const std::string& name = w.back();
    if (looks_like_asset_ref(name)) return line;
    const fs::path here = dir / name;
    const fs::path at_obj = obj_dir / name;
    const bool use_obj_dir = !fs::path(name).is_absolute() && !unreadable_reason(here).empty() &&
                             unreadable_reason(at_obj).empty();
    const std::string ref =
        nested(path, "MTL", "map_Kd", name, use_obj_dir ? obj_dir : dir, Format::plain);
    changed = true;
    const size_t at = line.rfind(name);
    return line.substr(0, at) + ref + line.substr(at + name.size());
  });
  return store_packed(path, text, changed ? &out : nullptr);
}

}  // namespace tally
