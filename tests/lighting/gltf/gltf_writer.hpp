#pragma once
// A minimal glTF 2.0 writer for the tests: the JSON document plus one binary buffer,
// saved as .gltf + .bin or packed as .glb. Accessors are float VEC2/VEC3 or uint32
// SCALAR, each in its own buffer view.
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

namespace tally::test {

struct GltfWriter {
  nlohmann::json doc = {{"asset", {{"version", "2.0"}}},
                        {"buffers", nlohmann::json::array()},
                        {"bufferViews", nlohmann::json::array()},
                        {"accessors", nlohmann::json::array()},
                        {"meshes", nlohmann::json::array()},
                        {"materials", nlohmann::json::array()},
                        {"nodes", nlohmann::json::array()},
                        {"scenes", nlohmann::json::array({{{"nodes", nlohmann::json::array()}}})},
                        {"scene", 0}};
  std::string bin;

  int view(const void* data, size_t bytes) {
    while (bin.size() % 4 != 0) bin.push_back('\0');
    const size_t off = bin.size();
    bin.append(static_cast<const char*>(data), bytes);
    doc["bufferViews"].push_back({{"buffer", 0}, {"byteOffset", off}, {"byteLength", bytes}});
    return static_cast<int>(doc["bufferViews"].size() - 1);
  }
  int floats(const std::vector<float>& v, int ncomp) {
    const int bv = view(v.data(), v.size() * 4);
    const char* type = ncomp == 2 ? "VEC2" : "VEC3";
    doc["accessors"].push_back({{"bufferView", bv}, {"componentType", 5126}, {"count", v.size() / static_cast<size_t>(ncomp)}, {"type", type}});
    return static_cast<int>(doc["accessors"].size() - 1);
  }
  int indices(const std::vector<uint32_t>& v) {
    const int bv = view(v.data(), v.size() * 4);
    doc["accessors"].push_back({{"bufferView", bv}, {"componentType", 5125}, {"count", v.size()}, {"type", "SCALAR"}});
    return static_cast<int>(doc["accessors"].size() - 1);
  }
  int material(const nlohmann::json& m) {
    doc["materials"].push_back(m);
    return static_cast<int>(doc["materials"].size() - 1);
  }
  // A mesh of one indexed triangle primitive; returns the mesh index.
  int mesh(const std::vector<float>& pos, const std::vector<uint32_t>& idx, int material,
           const std::vector<float>& normals = {}, const std::vector<float>& uvs = {}) {
    nlohmann::json attrs = {{"POSITION", floats(pos, 3)}};
    if (!normals.empty()) attrs["NORMAL"] = floats(normals, 3);
    if (!uvs.empty()) attrs["TEXCOORD_0"] = floats(uvs, 2);
    nlohmann::json prim = {{"attributes", attrs}, {"indices", indices(idx)}};
    if (material >= 0) prim["material"] = material;
    doc["meshes"].push_back({{"primitives", nlohmann::json::array({prim})}});
    return static_cast<int>(doc["meshes"].size() - 1);
  }
  // Adds a node (a root of the scene unless `root` is false); returns its index.
  int node(const nlohmann::json& n, bool root = true) {
    doc["nodes"].push_back(n);
    const int i = static_cast<int>(doc["nodes"].size() - 1);
    if (root) doc["scenes"][0]["nodes"].push_back(i);
    return i;
  }
  void light(const nlohmann::json& l) {
    doc["extensionsUsed"] = {"KHR_lights_punctual", "KHR_materials_emissive_strength"};
    doc["extensions"]["KHR_lights_punctual"]["lights"].push_back(l);
  }

  // name.gltf + name.bin (the buffer's uri, or `uri` when given).
  void save_gltf(const std::filesystem::path& dir, const std::string& name, const std::string& uri = "") const {
    nlohmann::json d = doc;
    d["buffers"] = {{{"byteLength", bin.size()}, {"uri", uri.empty() ? name + ".bin" : uri}}};
    std::ofstream(dir / (name + ".gltf")) << d.dump(1);
    if (uri.empty()) std::ofstream(dir / (name + ".bin"), std::ios::binary) << bin;
  }
  std::string glb() const {
    nlohmann::json d = doc;
    d["buffers"] = {{{"byteLength", bin.size()}}};
    std::string js = d.dump();
    while (js.size() % 4 != 0) js.push_back(' ');
    std::string b = bin;
    while (b.size() % 4 != 0) b.push_back('\0');
    std::string out;
    auto u32 = [&](uint32_t x) { out.append(reinterpret_cast<const char*>(&x), 4); };
    u32(0x46546C67u);
    u32(2);
    u32(static_cast<uint32_t>(12 + 8 + js.size() + 8 + b.size()));
    u32(static_cast<uint32_t>(js.size()));
    u32(0x4E4F534Au);
    out += js;
    u32(static_cast<uint32_t>(b.size()));
    u32(0x004E4942u);
    out += b;
    return out;
  }
};

}  // namespace tally::test
