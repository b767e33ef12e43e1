#include "common/lighting/scene_json.hpp"

#include "common/image/image_decode.hpp"
#include "common/lighting/asset_resolver.hpp"
#include "common/lighting/environment_map.hpp"
#include "common/lighting/obj_scene.hpp"
#include "common/lighting/texture.hpp"
#include "common/sampling/safe_math.hpp"

#include <fmt/format.h>

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

std::vector<Shape> parse_shape(SpecReader r, Scene& scene, const JobLimits& limits, size_t triangles_so_far) {
  Shape s;
  s.pointer = r.pointer();
  const std::string type = r.enumeration("type", {"mesh", "sphere", "quad", "disk", "triangle"});
  if (type == "mesh" && r.has("obj") && !r.has("material")) {  // materials from the OBJ's .mtl
    const std::string rel = r.string("obj", 1024);
    std::vector<Shape> shapes = load_obj(rel, r.pointer_of("obj"), scene_asset_reader(limits), limits, std::nullopt, scene);
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
      std::vector<Shape> shapes = load_obj(rel, r.pointer_of("obj"), scene_asset_reader(limits), limits, s.material, scene);
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
      if (scene.vertex_count() + vj.size() / 3 > limits.max_vertices) {
        throw SpecError(vp, fmt::format("more than {} vertices in the scene (max_vertices)", limits.max_vertices));
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
    if (scene.material_model) scene.materials.back().model = *scene.material_model;
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
    ImageDecodeLimits dl;
    dl.max_pixels = kMaxEnvironmentTexels;
    dl.max_channels = static_cast<uint32_t>(std::min<size_t>(limits.max_image_channels, UINT32_MAX));
    dl.max_bytes = limits.max_decode_bytes > scene.decode_bytes ? limits.max_decode_bytes - scene.decode_bytes : 0;
    dl.kept_bytes_per_pixel = kEnvironmentTexelBytes;
    im = decode_image(bytes, dl);
    scene.decode_bytes += im.charged_bytes;
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
  // "material_model" sets the form of every metallic-roughness material (bsdf.hpp); absent,
  // glTF files' materials take glTF's reference form and JSON materials the
  // energy-conserving one.
  std::optional<MaterialModel>& model = scene.material_model;
  if (r.has("material_model")) {
    model = r.enumeration("material_model", {"gltf_reference", "energy_conserving"}) == "gltf_reference"
                ? MaterialModel::gltf_reference
                : MaterialModel::energy_conserving;
  }
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
    if (sj->size() > limits.max_shapes) {
      throw SpecError(sp, fmt::format("{} shapes, more than the limit of {} (max_shapes)", sj->size(), limits.max_shapes));
    }
    for (size_t i = 0; i < sj->size(); ++i) {
      const nlohmann::json& e = (*sj)[i];
      if (e.is_object() && e.contains("type") && e["type"] == "gltf") {
        parse_gltf(SpecReader(e, json_pointer_append(sp, i)), scene, limits);
        continue;
      }
      for (Shape& s : parse_shape(SpecReader(e, json_pointer_append(sp, i)), scene, limits, scene.triangle_count())) {
        if (scene.shapes.size() >= limits.max_shapes) {
          throw SpecError(sp, fmt::format("more than {} shapes in the scene (max_shapes)", limits.max_shapes));
        }
        scene.shapes.push_back(std::move(s));
      }
    }
  }
  if (model) {
    for (Material& m : scene.materials) m.model = *model;
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
