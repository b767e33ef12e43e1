#include "common/lighting/scene_json.hpp"

#include "common/image/image_decode.hpp"
#include "common/lighting/asset_resolver.hpp"
#include "common/lighting/environment_map.hpp"
#include "common/lighting/texture.hpp"
#include "common/sampling/safe_math.hpp"

#include <fmt/format.h>
#include <tiny_obj_loader.h>

#include <cmath>
#include <limits>
#include <map>
#include <optional>

namespace tally {

namespace {

constexpr double kCoordLimit = 1e12;

Vec3 to_vec3(const std::vector<double>& v) { return {v[0], v[1], v[2]}; }

Rgb read_rgb(SpecReader& r, std::string_view key, double hi) {
  return to_vec3(r.numbers(key, 3, 3, 0.0, hi));
}

Material parse_material(SpecReader r, std::string name) {
  Material m;
  m.name = std::move(name);
  const std::string type =
      r.enumeration("type", {"diffuse", "emissive", "mirror", "phong", "ggx", "metallic_roughness"});
  if (type == "diffuse") {
    m.type = MaterialType::diffuse;
    m.albedo = read_rgb(r, "albedo", 1.0);
  } else if (type == "emissive") {
    m.type = MaterialType::emissive;
    m.emission = read_rgb(r, "radiance", 1e12);
    m.albedo = r.has("albedo") ? read_rgb(r, "albedo", 1.0) : Rgb{};
    m.two_sided = r.boolean_or("two_sided", false);
  } else if (type == "mirror") {
    m.type = MaterialType::mirror;
    m.reflectance = r.has("reflectance") ? read_rgb(r, "reflectance", 1.0) : Rgb{1, 1, 1};
  } else if (type == "phong") {
    m.type = MaterialType::phong;
    m.reflectance = read_rgb(r, "reflectance", 1.0);
    m.exponent = r.number("exponent", 0.0, 1e6);
  } else {
    // GGX: "ggx" is a rough metal (F0 = reflectance), "metallic_roughness" glTF's model.
    m.type = MaterialType::metallic_roughness;
    if (type == "ggx") {
      m.base_color = read_rgb(r, "reflectance", 1.0);
      m.metallic = 1.0;
    } else {
      m.base_color = read_rgb(r, "base_color", 1.0);
      m.metallic = r.number("metallic", 0.0, 1.0);
    }
    m.roughness = r.number("roughness", 0.0, 1.0);
    if (r.has("emission")) m.emission = read_rgb(r, "emission", 1e12);
    m.two_sided = r.boolean_or("two_sided", false);
  }
  r.finish();
  return m;
}

void add_triangle_mesh(Shape& s, std::vector<Vec3> vertices, std::vector<std::array<uint32_t, 3>> tris) {
  s.vertices = std::move(vertices);
  s.triangles = std::move(tris);
}

// The `mtllib` names of an OBJ (each line may list several files).
std::vector<std::string> mtllib_names(const std::string& obj_text) {
  std::vector<std::string> out;
  size_t pos = 0;
  while (pos < obj_text.size()) {
    size_t end = obj_text.find('\n', pos);
    if (end == std::string::npos) end = obj_text.size();
    std::string line = obj_text.substr(pos, end - pos);
    pos = end + 1;
    const size_t b = line.find_first_not_of(" \t");
    if (b == std::string::npos || line.compare(b, 6, "mtllib") != 0) continue;
    size_t i = b + 6;
    if (i < line.size() && line[i] != ' ' && line[i] != '\t') continue;
    while (i < line.size()) {
      const size_t w = line.find_first_not_of(" \t\r", i);
      if (w == std::string::npos) break;
      const size_t e = std::min(line.find_first_of(" \t\r", w), line.size());
      out.push_back(line.substr(w, e - w));
      i = e;
    }
  }
  return out;
}

Rgb mtl_rgb(const tinyobj::real_t* v) {
  Rgb c{static_cast<double>(v[0]), static_cast<double>(v[1]), static_cast<double>(v[2])};
  for (int k = 0; k < 3; ++k) {
    const double x = c[k];
    const double clamped = std::isfinite(x) ? std::clamp(x, 0.0, 1e12) : 0.0;
    if (k == 0) c.x = clamped;
    if (k == 1) c.y = clamped;
    if (k == 2) c.z = clamped;
  }
  return c;
}

// An .mtl material as a tally material (docs/lighting.md, "OBJ materials"): Kd -> the
// Lambertian albedo, Ks + Ns -> a normalised Phong lobe, Ke -> emission; where Kd + Ks
// exceeds 1 both are scaled down so the material cannot create energy. map_Kd (read by
// the caller) multiplies the albedo.
Material mtl_material(const tinyobj::material_t& t, const std::string& name) {
  Material m;
  m.name = name;
  Rgb kd = mtl_rgb(t.diffuse), ks = mtl_rgb(t.specular);
  const Rgb ke = mtl_rgb(t.emission);
  const double peak = max_component(kd + ks);
  if (peak > 1.0) {
    kd = kd / peak;
    ks = ks / peak;
  }
  if (!is_black(ks)) {
    m.type = MaterialType::phong;
    m.reflectance = ks;
    m.exponent = std::isfinite(t.shininess) ? std::clamp(static_cast<double>(t.shininess), 0.0, 1e6) : 0.0;
    m.albedo = kd;
  } else {
    m.type = is_black(ke) ? MaterialType::diffuse : MaterialType::emissive;
    m.albedo = kd;
  }
  m.emission = ke;
  return m;
}

// The map_Kd texture of an .mtl material as an index into scene.textures (-1: none).
// The file is named relative to the OBJ's directory and read through `read` (the same
// checks as every asset); it is decoded as sRGB unless "-colorspace linear"; "-clamp on"
// clamps to the edge, otherwise it repeats. Other options are refused.
int32_t mtl_texture(const tinyobj::material_t& t, const std::string& dir, const std::string& pointer,
                    const AssetReader& read, const JobLimits& limits, Scene& scene) {
  if (t.diffuse_texname.empty()) return -1;
  const tinyobj::texture_option_t& o = t.diffuse_texopt;
  const std::string what = fmt::format("material \"{}\": map_Kd \"{}\"", t.name, t.diffuse_texname);
  if (o.origin_offset[0] != 0 || o.origin_offset[1] != 0 || o.origin_offset[2] != 0 || o.scale[0] != 1 ||
      o.scale[1] != 1 || o.scale[2] != 1 || o.turbulence[0] != 0 || o.turbulence[1] != 0 || o.turbulence[2] != 0 ||
      o.brightness != 0 || o.contrast != 1) {
    throw SpecError(pointer, what + ": the options -o, -s, -t and -mm are not supported");
  }
  if (!o.colorspace.empty() && o.colorspace != "sRGB" && o.colorspace != "linear") {
    throw SpecError(pointer, what + fmt::format(": unknown -colorspace \"{}\" (sRGB or linear)", o.colorspace));
  }
  const bool srgb = o.colorspace != "linear";
  const std::string bytes = [&] {
    try {
      return read(dir + t.diffuse_texname, pointer);
    } catch (const SpecError& e) {
      throw SpecError(pointer, fmt::format("{}: {}", what, e.detail()));
    }
  }();
  const uint64_t left = limits.max_texture_bytes > scene.texture_bytes ? limits.max_texture_bytes - scene.texture_bytes : 0;
  Texture tex;
  try {
    tex.texels = decode_texels(bytes, srgb, left / kTexelBytes);
  } catch (const std::exception& e) {
    throw SpecError(pointer, fmt::format("{}: cannot be used as a texture: {}", what, e.what()));
  }
  tex.wrap_s = tex.wrap_t = o.clamp ? TextureWrap::clamp_to_edge : TextureWrap::repeat;
  scene.texture_bytes += tex.texels->bytes();
  if (scene.textures.size() >= 4096) throw SpecError(pointer, "too many textures (limit 4096)");
  scene.textures.push_back(std::move(tex));
  return static_cast<int32_t>(scene.textures.size() - 1);
}

// Loads an OBJ into one shape per material. With `material` set (the scene names one)
// every face gets it and `mtllib` opens nothing; otherwise the .mtl files it names are
// read through `read` (relative to the OBJ's directory, with the same checks as every
// asset) and each face gets its `usemtl` material.
std::vector<Shape> load_obj(const std::string& relative, const std::string& pointer, const AssetReader& read,
                            const JobLimits& limits, size_t triangles_so_far, std::optional<uint32_t> material,
                            Scene& scene) {
  tinyobj::ObjReaderConfig config;
  config.triangulate = true;
  config.vertex_color = false;
  const std::string text = read(relative, pointer);
  std::string mtl_text;
  if (!material) {
    const auto slash = relative.find_last_of('/');
    const std::string dir = slash == std::string::npos ? std::string() : relative.substr(0, slash + 1);
    for (const std::string& lib : mtllib_names(text)) mtl_text += read(dir + lib, pointer) + "\n";
  }
  tinyobj::ObjReader reader;
  if (!reader.ParseFromString(text, mtl_text, config)) {
    throw SpecError(pointer, fmt::format("cannot read OBJ: {}", reader.Error()));
  }
  const auto& attrib = reader.GetAttrib();
  const size_t nv = attrib.vertices.size() / 3;
  std::vector<Vec3> verts(nv);
  for (size_t i = 0; i < nv; ++i) {
    verts[i] = {attrib.vertices[3 * i], attrib.vertices[3 * i + 1], attrib.vertices[3 * i + 2]};
    for (int c = 0; c < 3; ++c) {
      if (!std::isfinite(verts[i][c]) || std::fabs(verts[i][c]) > kCoordLimit) {
        throw SpecError(pointer, fmt::format("OBJ vertex {} is not finite or out of range", i));
      }
    }
  }
  // Faces grouped by OBJ material (-1: none), in order of first use.
  std::vector<int> group_ids;
  std::vector<std::vector<std::array<uint32_t, 3>>> groups;
  std::vector<std::vector<std::array<int, 3>>> group_vt;  // vt indices of the same faces (-1: none)
  const size_t nvt = attrib.texcoords.size() / 2;
  size_t total = 0;
  for (const auto& shape : reader.GetShapes()) {
    const auto& idx = shape.mesh.indices;
    if (triangles_so_far + total + idx.size() / 3 > limits.max_triangles) {
      throw SpecError(pointer, fmt::format("too many triangles (limit {})", limits.max_triangles));
    }
    for (size_t f = 0; f + 2 < idx.size(); f += 3) {
      std::array<uint32_t, 3> t{};
      std::array<int, 3> vt{};
      for (size_t k = 0; k < 3; ++k) {
        const int vi = idx[f + k].vertex_index;
        if (vi < 0 || static_cast<size_t>(vi) >= nv) throw SpecError(pointer, "OBJ index out of range");
        t[k] = static_cast<uint32_t>(vi);
        const int ti = idx[f + k].texcoord_index;
        if (ti >= 0 && static_cast<size_t>(ti) >= nvt) throw SpecError(pointer, "OBJ texture coordinate index out of range");
        vt[k] = ti;
      }
      const int mid = material ? -1 : (f / 3 < shape.mesh.material_ids.size() ? shape.mesh.material_ids[f / 3] : -1);
      auto it = std::find(group_ids.begin(), group_ids.end(), mid);
      if (it == group_ids.end()) {
        group_ids.push_back(mid);
        groups.emplace_back();
        group_vt.emplace_back();
        it = group_ids.end() - 1;
      }
      groups[static_cast<size_t>(it - group_ids.begin())].push_back(t);
      group_vt[static_cast<size_t>(it - group_ids.begin())].push_back(vt);
      ++total;
    }
  }
  if (total == 0) throw SpecError(pointer, "OBJ file has no triangles");
  const auto& mats = reader.GetMaterials();
  const auto slash = relative.find_last_of('/');
  const std::string dir = slash == std::string::npos ? std::string() : relative.substr(0, slash + 1);
  std::vector<Shape> out;
  for (size_t g = 0; g < groups.size(); ++g) {
    Shape s;
    s.type = ShapeType::mesh;
    s.pointer = pointer;
    if (material) {
      s.material = *material;
    } else {
      const int mid = group_ids[g];
      if (mid < 0 || static_cast<size_t>(mid) >= mats.size()) {
        throw SpecError(pointer, "some OBJ faces have no .mtl material (no usemtl, or an unknown one) and the shape names no \"material\"");
      }
      if (scene.materials.size() >= 4096) throw SpecError(pointer, "too many materials (limit 4096)");
      const tinyobj::material_t& mt = mats[static_cast<size_t>(mid)];
      Material m = mtl_material(mt, relative + "#" + mt.name);
      m.base_color_texture = mtl_texture(mt, dir, pointer, read, limits, scene);
      scene.materials.push_back(std::move(m));
      s.material = static_cast<uint32_t>(scene.materials.size() - 1);
    }
    if (scene.materials[s.material].textured()) {
      // One vertex per distinct (v, vt) pair, so each carries its texture coordinates.
      // OBJ's v runs up the image, glTF's (and tally's) down: v -> 1 - v.
      std::map<std::pair<uint32_t, int>, uint32_t> seen;
      for (size_t f = 0; f < groups[g].size(); ++f) {
        for (size_t k = 0; k < 3; ++k) {
          const int ti = group_vt[g][f][k];
          if (ti < 0) {
            throw SpecError(pointer, fmt::format("material \"{}\" has a texture, but face {} of its faces has no vt",
                                                 scene.materials[s.material].name, f));
          }
          const auto key = std::make_pair(groups[g][f][k], ti);
          auto [it, fresh] = seen.emplace(key, static_cast<uint32_t>(s.vertices.size()));
          if (fresh) {
            s.vertices.push_back(verts[key.first]);
            s.uvs.push_back({attrib.texcoords[2 * static_cast<size_t>(ti)],
                             1.0 - static_cast<double>(attrib.texcoords[2 * static_cast<size_t>(ti) + 1])});
          }
          groups[g][f][k] = it->second;
        }
      }
      for (const Vec2& uv : s.uvs) {
        if (!std::isfinite(uv.x) || !std::isfinite(uv.y)) throw SpecError(pointer, "OBJ texture coordinates must be finite");
      }
      s.triangles = std::move(groups[g]);
      out.push_back(std::move(s));
      continue;
    }
    // Every group keeps all vertices (simple; Embree ignores unreferenced ones).
    add_triangle_mesh(s, g + 1 == groups.size() ? std::move(verts) : verts, std::move(groups[g]));
    out.push_back(std::move(s));
  }
  return out;
}

std::vector<Shape> parse_shape(SpecReader r, Scene& scene, const JobLimits& limits, size_t triangles_so_far) {
  Shape s;
  s.pointer = r.pointer();
  const std::string type = r.enumeration("type", {"mesh", "sphere", "quad", "disk", "triangle"});
  if (type == "mesh" && r.has("obj") && !r.has("material")) {  // materials from the OBJ's .mtl
    const std::string rel = r.string("obj", 1024);
    std::vector<Shape> shapes = load_obj(rel, r.pointer_of("obj"), scene_asset_reader(limits), limits,
                                         triangles_so_far, std::nullopt, scene);
    r.finish();
    return shapes;
  }
  s.material = parse_material_ref(r.at("material"), r.pointer_of("material"), scene);
  if (type == "sphere") {
    s.type = ShapeType::sphere;
    s.center = read_vec3(r, "center");
    s.radius = r.number("radius", 0.0, kCoordLimit);
  } else if (type == "disk") {
    s.type = ShapeType::disk;
    s.center = read_vec3(r, "center");
    s.normal = read_direction(r, "normal");
    s.radius = r.number("radius", 0.0, kCoordLimit);
  } else if (type == "quad") {
    s.type = ShapeType::quad;
    s.corner = read_vec3(r, "corner");
    s.edge_u = read_vec3(r, "edge_u");
    s.edge_v = read_vec3(r, "edge_v");
    const Vec3 a = s.corner, b = a + s.edge_u, c = b + s.edge_v, d = a + s.edge_v;
    add_triangle_mesh(s, {a, b, c, d}, {{0, 1, 2}, {0, 2, 3}});
  } else if (type == "triangle") {
    s.type = ShapeType::mesh;
    const nlohmann::json& vj = r.at("vertices");
    const std::string vp = r.pointer_of("vertices");
    if (!vj.is_array() || vj.size() != 3) throw SpecError(vp, "must be an array of 3 points");
    std::vector<Vec3> v;
    for (size_t i = 0; i < 3; ++i) {
      const std::string p = json_pointer_append(vp, i);
      if (!vj[i].is_array() || vj[i].size() != 3) throw SpecError(p, "must be [x, y, z]");
      v.push_back({spec_number(vj[i][0], json_pointer_append(p, size_t{0}), -kCoordLimit, kCoordLimit),
                   spec_number(vj[i][1], json_pointer_append(p, size_t{1}), -kCoordLimit, kCoordLimit),
                   spec_number(vj[i][2], json_pointer_append(p, size_t{2}), -kCoordLimit, kCoordLimit)});
    }
    add_triangle_mesh(s, std::move(v), {{0, 1, 2}});
  } else {  // mesh: inline or OBJ
    s.type = ShapeType::mesh;
    if (r.has("obj")) {
      const std::string rel = r.string("obj", 1024);
      std::vector<Shape> shapes = load_obj(rel, r.pointer_of("obj"), scene_asset_reader(limits), limits,
                                           triangles_so_far, s.material, scene);
      s.vertices = std::move(shapes[0].vertices);
      s.triangles = std::move(shapes[0].triangles);
      s.uvs = std::move(shapes[0].uvs);
    } else {
      const nlohmann::json& vj = r.at("vertices");
      const nlohmann::json& ij = r.at("indices");
      const std::string vp = r.pointer_of("vertices"), ip = r.pointer_of("indices");
      if (!vj.is_array() || vj.size() % 3 != 0 || vj.empty()) {
        throw SpecError(vp, "must be a flat array of x, y, z triples");
      }
      if (!ij.is_array() || ij.size() % 3 != 0 || ij.empty()) {
        throw SpecError(ip, "must be a flat array of vertex index triples");
      }
      if (vj.size() / 3 > limits.max_table_size) {
        throw SpecError(vp, fmt::format("too many vertices (limit {})", limits.max_table_size));
      }
      if (triangles_so_far + ij.size() / 3 > limits.max_triangles) {
        throw SpecError(ip, fmt::format("too many triangles (limit {})", limits.max_triangles));
      }
      std::vector<Vec3> v(vj.size() / 3);
      for (size_t i = 0; i < v.size(); ++i) {
        v[i] = {spec_number(vj[3 * i], json_pointer_append(vp, 3 * i), -kCoordLimit, kCoordLimit),
                spec_number(vj[3 * i + 1], json_pointer_append(vp, 3 * i + 1), -kCoordLimit, kCoordLimit),
                spec_number(vj[3 * i + 2], json_pointer_append(vp, 3 * i + 2), -kCoordLimit, kCoordLimit)};
      }
      std::vector<std::array<uint32_t, 3>> t(ij.size() / 3);
      for (size_t i = 0; i < ij.size(); ++i) {
        const double x = spec_number(ij[i], json_pointer_append(ip, i), 0.0,
                                     static_cast<double>(v.size() - 1));
        if (x != std::floor(x)) throw SpecError(json_pointer_append(ip, i), "must be an integer");
        t[i / 3][i % 3] = static_cast<uint32_t>(x);
      }
      add_triangle_mesh(s, std::move(v), std::move(t));
    }
  }
  r.finish();
  return {std::move(s)};
}

// {"type": "gltf", "file": "x.gltf" | "x.glb", "camera": index | name, "resolution": [w, h]}
void parse_gltf(SpecReader r, Scene& scene, const JobLimits& limits) {
  r.enumeration("type", {"gltf"});
  GltfRequest req;
  req.file = r.string("file", 1024);
  req.pointer = r.pointer_of("file");
  if (r.has("camera")) {
    const nlohmann::json& c = r.at("camera");
    req.camera_pointer = r.pointer_of("camera");
    if (c.is_number_integer() && c.get<int64_t>() >= 0) {
      req.camera = static_cast<size_t>(c.get<int64_t>());
    } else if (c.is_string()) {
      req.camera = c.get<std::string>();
    } else {
      throw SpecError(req.camera_pointer, "must be a camera index or name");
    }
    if (scene.camera) throw SpecError(req.camera_pointer, "the scene already has a \"camera\"");
    const std::vector<double> res = r.numbers("resolution", 2, 2, 1, 1 << 20);
    if (res[0] != std::floor(res[0]) || res[1] != std::floor(res[1])) {
      throw SpecError(r.pointer_of("resolution"), "must be two integers [width, height]");
    }
    req.width = static_cast<int>(res[0]);
    req.height = static_cast<int>(res[1]);
    if (static_cast<uint64_t>(req.width) * static_cast<uint64_t>(req.height) > limits.max_pixels) {
      throw SpecError(r.pointer_of("resolution"),
                      fmt::format("{}x{} pixels exceed the limit of {}", req.width, req.height, limits.max_pixels));
    }
  } else if (r.has("resolution")) {
    throw SpecError(r.pointer_of("resolution"), "is only used with \"camera\"");
  }
  r.finish();
  load_gltf(scene, req, scene_asset_reader(limits), limits);
}

DeltaLight parse_delta_light(SpecReader& r, const std::string& type) {
  DeltaLight l;
  if (type == "point") {
    l.type = DeltaLightType::point;
    l.position = read_vec3(r, "position");
    l.intensity = read_rgb(r, "intensity", 1e15);
  } else if (type == "spot") {
    l.type = DeltaLightType::spot;
    l.position = read_vec3(r, "position");
    l.direction = read_direction(r, "direction");
    l.intensity = read_rgb(r, "intensity", 1e15);
    const double outer = r.number_or("outer_cone_deg", 45.0, 0.0, 90.0);
    const double inner = r.number_or("inner_cone_deg", 0.0, 0.0, 90.0);
    if (!(inner < outer)) throw SpecError(r.pointer_of("inner_cone_deg"), "must be smaller than outer_cone_deg");
    l.cos_inner = std::cos(inner * kPi / 180.0);
    l.cos_outer = std::cos(outer * kPi / 180.0);
  } else {
    l.type = DeltaLightType::directional;
    l.direction = read_direction(r, "direction");
    l.intensity = read_rgb(r, "irradiance", 1e15);
  }
  return l;
}

}  // namespace

Vec3 read_vec3(SpecReader& r, std::string_view key) {
  return to_vec3(r.numbers(key, 3, 3, -kCoordLimit, kCoordLimit));
}

Vec3 read_direction(SpecReader& r, std::string_view key) {
  const Vec3 v = read_vec3(r, key);
  const double len = length(v);
  if (!(len > 1e-300) || !std::isfinite(len)) {
    throw SpecError(r.pointer_of(key), "must be a non-zero direction");
  }
  return v / len;
}

uint32_t parse_material_ref(const nlohmann::json& j, const std::string& pointer, Scene& scene) {
  if (j.is_string()) {
    const std::string& name = j.get_ref<const std::string&>();
    for (size_t i = 0; i < scene.materials.size(); ++i) {
      if (scene.materials[i].name == name) return static_cast<uint32_t>(i);
    }
    throw SpecError(pointer, fmt::format("unknown material \"{}\"", name));
  }
  if (j.is_object()) {
    scene.materials.push_back(parse_material(SpecReader(j, pointer), ""));
    return static_cast<uint32_t>(scene.materials.size() - 1);
  }
  throw SpecError(pointer, "must be a material name or a material object");
}

namespace {

// The largest environment map read (4096 x 2048): about 70 bytes a texel once its
// sampling tables are built, ~0.6 GB at this size.
constexpr uint64_t kMaxEnvironmentTexels = uint64_t{1} << 23;

// {"type": "sky", "radiance": [r, g, b]}, or an environment map:
// {"type": "sky", "map": "<file or sha256:>", "intensity": s = 1, "rotation_deg": a = 0}
// (environment_map.hpp for the direction convention). A map whose texels are all equal
// becomes the constant sky of that radiance, bit for bit the same light.
void parse_sky(SpecReader& l, Scene& scene, const JobLimits& limits) {
  if (!l.has("map")) {
    for (const char* key : {"intensity", "rotation_deg"}) {
      if (l.has(key)) throw SpecError(l.pointer_of(key), "applies to an environment map only (give \"map\")");
    }
    scene.sky = read_rgb(l, "radiance", 1e12);
    return;
  }
  if (l.has("radiance")) {
    throw SpecError(l.pointer_of("radiance"),
                    "give either \"radiance\" (a constant sky) or \"map\" (an environment map), not both");
  }
  const std::string map_ptr = l.pointer_of("map");
  const std::string name = l.string("map", 4096);
  const double intensity = l.number_or("intensity", 1.0, 0.0, 1e12);
  const double rotation = l.number_or("rotation_deg", 0.0, -360.0, 360.0);
  const std::string bytes = read_scene_file(name, limits, map_ptr);
  auto refuse = [&](const std::string& why) { return SpecError(map_ptr, fmt::format("environment map \"{}\": {}", name, why)); };
  const std::optional<std::string> format = sniff_image_format(bytes);
  if (!format || (*format != "openexr" && *format != "hdr")) {
    throw refuse(fmt::format("not an OpenEXR or Radiance .hdr image{} (an environment map holds linear HDR radiance)",
                             format ? ", a " + *format + " file" : ""));
  }
  DecodedImage im;
  try {
    im = decode_image(bytes, kMaxEnvironmentTexels);
  } catch (const std::runtime_error& e) {
    throw refuse(e.what());
  }
  // R, G, B from the first three channels (alpha and others ignored); 1-2 channels: grey.
  const size_t n = static_cast<size_t>(im.width) * static_cast<size_t>(im.height);
  const size_t nc = static_cast<size_t>(im.channels);
  if (im.bits != 32 || nc == 0 || im.floats.size() != n * nc) throw refuse("the image module returned no float pixels");
  std::vector<float> rgb(3 * n);
  for (size_t i = 0; i < n; ++i) {
    for (size_t c = 0; c < 3; ++c) rgb[3 * i + c] = im.floats[nc * i + (nc >= 3 ? c : 0)];
  }
  std::shared_ptr<const EnvironmentMap> env;
  try {
    env = std::make_shared<const EnvironmentMap>(im.width, im.height, rgb, intensity, rotation);
  } catch (const std::invalid_argument& e) {
    throw SpecError(map_ptr, fmt::format("environment map \"{}\": {}", name, e.what()));
  }
  if (const std::optional<Rgb> c = env->constant()) {
    scene.sky = *c;
  } else {
    scene.environment = std::move(env);
  }
}

}  // namespace

Scene parse_scene(SpecReader& r, const JobLimits& limits) {
  Scene scene;
  if (r.has("camera")) {
    SpecReader c = r.object("camera");
    Camera cam;
    cam.position = read_vec3(c, "position");
    cam.look_at = read_vec3(c, "look_at");
    cam.up = c.has("up") ? read_direction(c, "up") : Vec3{0, 1, 0};
    cam.fov_deg = c.number_or("fov_deg", 45.0, 1e-3, 179.0);
    const std::vector<double> res = c.numbers("resolution", 2, 2, 1, 1 << 20);
    if (res[0] != std::floor(res[0]) || res[1] != std::floor(res[1])) {
      throw SpecError(c.pointer_of("resolution"), "must be two integers [width, height]");
    }
    cam.width = static_cast<int>(res[0]);
    cam.height = static_cast<int>(res[1]);
    if (static_cast<uint64_t>(cam.width) * static_cast<uint64_t>(cam.height) > limits.max_pixels) {
      throw SpecError(c.pointer_of("resolution"),
                      fmt::format("{}x{} pixels exceed the limit of {}", cam.width, cam.height, limits.max_pixels));
    }
    const Vec3 fwd = cam.look_at - cam.position;
    if (!(length(fwd) > 0)) throw SpecError(c.pointer_of("look_at"), "must differ from position");
    if (!(length(cross(fwd, cam.up)) > 1e-12 * length(fwd))) {
      throw SpecError(c.pointer_of("up"), "must not be parallel to the viewing direction");
    }
    c.finish();
    scene.camera = cam;
  }
  if (const nlohmann::json* mj = r.find("materials")) {
    const std::string mp = r.pointer_of("materials");
    if (!mj->is_object()) throw SpecError(mp, "must be an object {name: material}");
    if (mj->size() > 4096) throw SpecError(mp, "too many materials (limit 4096)");
    for (auto it = mj->begin(); it != mj->end(); ++it) {
      scene.materials.push_back(parse_material(SpecReader(it.value(), json_pointer_append(mp, it.key())), it.key()));
    }
  }
  if (const nlohmann::json* sj = r.find("shapes")) {
    const std::string sp = r.pointer_of("shapes");
    if (!sj->is_array()) throw SpecError(sp, "must be an array");
    if (sj->size() > 65536) throw SpecError(sp, "too many shapes (limit 65536)");
    for (size_t i = 0; i < sj->size(); ++i) {
      const nlohmann::json& e = (*sj)[i];
      if (e.is_object() && e.contains("type") && e["type"] == "gltf") {
        parse_gltf(SpecReader(e, json_pointer_append(sp, i)), scene, limits);
        continue;
      }
      for (Shape& s : parse_shape(SpecReader(e, json_pointer_append(sp, i)), scene, limits, scene.triangle_count())) {
        if (scene.shapes.size() >= 65536) throw SpecError(sp, "too many shapes (limit 65536)");
        scene.shapes.push_back(std::move(s));
      }
    }
  }
  for (const Shape& s : scene.shapes) {
    if (scene.materials[s.material].textured() && s.uvs.empty()) {
      throw SpecError(s.pointer, fmt::format("material \"{}\" has textures, but the shape has no texture coordinates",
                                             scene.materials[s.material].name));
    }
  }
  if (const nlohmann::json* lj = r.find("lights")) {
    const std::string lp = r.pointer_of("lights");
    if (!lj->is_array()) throw SpecError(lp, "must be an array");
    if (lj->size() > 4096) throw SpecError(lp, "too many lights (limit 4096)");
    for (size_t i = 0; i < lj->size(); ++i) {
      SpecReader l((*lj)[i], json_pointer_append(lp, i));
      const std::string type = l.enumeration("type", {"point", "spot", "directional", "sky"});
      if (type == "sky") {
        if (scene.sky || scene.environment) throw SpecError(l.pointer(), "only one sky is allowed");
        parse_sky(l, scene, limits);
      } else {
        scene.delta_lights.push_back(parse_delta_light(l, type));
      }
      l.finish();
    }
  }
  r.finish();
  return scene;
}

}  // namespace tally
