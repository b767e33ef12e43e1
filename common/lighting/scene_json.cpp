#include "common/lighting/scene_json.hpp"

#include "common/lighting/asset_resolver.hpp"

#include <fmt/format.h>
#include <tiny_obj_loader.h>

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstring>
#include <limits>
#include <map>

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
  const std::string type = r.enumeration("type", {"diffuse", "emissive", "mirror", "phong"});
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
  } else {
    m.type = MaterialType::phong;
    m.reflectance = read_rgb(r, "reflectance", 1.0);
    m.exponent = r.number("exponent", 0.0, 1e6);
  }
  r.finish();
  return m;
}

void add_triangle_mesh(Shape& s, std::vector<Vec3> vertices, std::vector<std::array<uint32_t, 3>> tris) {
  s.vertices = std::move(vertices);
  s.triangles = std::move(tris);
}

void load_obj(Shape& s, const std::filesystem::path& path, const std::string& pointer,
              const JobLimits& limits, size_t triangles_so_far) {
  tinyobj::ObjReaderConfig config;
  config.triangulate = true;
  config.vertex_color = false;
  // The OBJ's text is read here, through read_asset_file. Its `mtllib` lines open
  // nothing: materials come from the scene JSON, and an mtllib path would escape the
  // asset directory's checks (and a FIFO there would block the thread forever).
  tinyobj::ObjReader reader;
  if (!reader.ParseFromString(read_asset_file(path, pointer), std::string(), config)) {
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
  std::vector<std::array<uint32_t, 3>> tris;
  for (const auto& shape : reader.GetShapes()) {
    const auto& idx = shape.mesh.indices;
    if (triangles_so_far + tris.size() + idx.size() / 3 > limits.max_table_size) {
      throw SpecError(pointer, fmt::format("too many triangles (limit {})", limits.max_table_size));
    }
    for (size_t f = 0; f + 2 < idx.size(); f += 3) {
      std::array<uint32_t, 3> t{};
      for (size_t k = 0; k < 3; ++k) {
        const int vi = idx[f + k].vertex_index;
        if (vi < 0 || static_cast<size_t>(vi) >= nv) throw SpecError(pointer, "OBJ index out of range");
        t[k] = static_cast<uint32_t>(vi);
      }
      tris.push_back(t);
    }
  }
  if (tris.empty()) throw SpecError(pointer, "OBJ file has no triangles");
  add_triangle_mesh(s, std::move(verts), std::move(tris));
}

Shape parse_shape(SpecReader r, Scene& scene, const JobLimits& limits, size_t triangles_so_far) {
  Shape s;
  s.pointer = r.pointer();
  const std::string type = r.enumeration("type", {"mesh", "sphere", "quad", "disk", "triangle"});
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
      load_obj(s, resolve_scene_file(rel, limits, r.pointer_of("obj")), r.pointer_of("obj"), limits,
               triangles_so_far);
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
      if (triangles_so_far + ij.size() / 3 > limits.max_table_size) {
        throw SpecError(ip, fmt::format("too many triangles (limit {})", limits.max_table_size));
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
  return s;
}

DeltaLight parse_delta_light(SpecReader& r, const std::string& type) {
  DeltaLight l;
  if (type == "point") {
    l.type = DeltaLightType::point;
    l.position = read_vec3(r, "position");
    l.intensity = read_rgb(r, "intensity", 1e15);
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

std::string read_asset_file(const std::filesystem::path& path, const std::string& pointer, size_t max_bytes) {
  // O_NOFOLLOW and O_NONBLOCK: a symlink or FIFO swapped in after resolve_asset's
  // checks neither escapes nor blocks; fstat on the open descriptor decides.
  const int fd = ::open(path.c_str(), O_RDONLY | O_NONBLOCK | O_NOFOLLOW | O_CLOEXEC);
  if (fd < 0) throw SpecError(pointer, fmt::format("cannot open asset: {}", std::strerror(errno)));
  struct Closer {
    int fd;
    ~Closer() { ::close(fd); }
  } closer{fd};
  struct stat st {};
  if (::fstat(fd, &st) != 0 || !S_ISREG(st.st_mode)) throw SpecError(pointer, "is not a regular file");
  if (static_cast<uint64_t>(st.st_size) > max_bytes) {
    throw SpecError(pointer, fmt::format("asset is larger than {} bytes", max_bytes));
  }
  std::string out(static_cast<size_t>(st.st_size), '\0');
  size_t got = 0;
  while (got < out.size()) {
    const ssize_t n = ::read(fd, out.data() + got, out.size() - got);
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) throw SpecError(pointer, fmt::format("cannot read asset: {}", std::strerror(errno)));
    if (n == 0) break;  // the file shrank
    got += static_cast<size_t>(n);
  }
  out.resize(got);
  return out;
}

std::filesystem::path resolve_asset(const std::string& asset_dir, const std::string& relative,
                                    const std::string& pointer) {
  namespace fs = std::filesystem;
  if (asset_dir.empty()) throw SpecError(pointer, "no asset directory is configured: OBJ files are not allowed");
  const fs::path rel(relative);
  if (rel.empty() || rel.is_absolute() || rel.has_root_name() || rel.has_root_directory()) {
    throw SpecError(pointer, "must be a relative path inside the asset directory");
  }
  for (const auto& part : rel) {
    if (part == "..") throw SpecError(pointer, "must not contain \"..\"");
  }
  std::error_code ec;
  const fs::path root = fs::canonical(asset_dir, ec);
  if (ec) throw SpecError(pointer, "the asset directory does not exist");
  const fs::path full = fs::canonical(root / rel, ec);  // resolves symlinks
  if (ec) throw SpecError(pointer, fmt::format("asset \"{}\" not found", relative));
  const auto [root_end, unused] = std::mismatch(root.begin(), root.end(), full.begin(), full.end());
  (void)unused;
  if (root_end != root.end()) throw SpecError(pointer, "resolves outside the asset directory");
  if (!fs::is_regular_file(full, ec)) throw SpecError(pointer, "is not a regular file");
  return full;
}

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
      scene.shapes.push_back(parse_shape(SpecReader((*sj)[i], json_pointer_append(sp, i)), scene,
                                         limits, scene.triangle_count()));
    }
  }
  if (const nlohmann::json* lj = r.find("lights")) {
    const std::string lp = r.pointer_of("lights");
    if (!lj->is_array()) throw SpecError(lp, "must be an array");
    if (lj->size() > 4096) throw SpecError(lp, "too many lights (limit 4096)");
    for (size_t i = 0; i < lj->size(); ++i) {
      SpecReader l((*lj)[i], json_pointer_append(lp, i));
      const std::string type = l.enumeration("type", {"point", "directional", "sky"});
      if (type == "sky") {
        if (scene.sky) throw SpecError(l.pointer(), "only one sky is allowed");
        scene.sky = read_rgb(l, "radiance", 1e12);
      } else {
        scene.delta_lights.push_back(parse_delta_light(l, type));
      }
      l.finish();
    }
  }
  r.finish();
  return scene;
}

void localize_scene(Scene& scene) {
  const SceneBounds b = scene_bounds(scene);
  const Vec3 origin = b.empty() ? Vec3{} : (b.lo + b.hi) * 0.5;
  scene.origin = origin;
  auto round_f = [](const Vec3& v) {
    return Vec3{static_cast<double>(static_cast<float>(v.x)), static_cast<double>(static_cast<float>(v.y)),
                static_cast<double>(static_cast<float>(v.z))};
  };
  for (Shape& s : scene.shapes) {
    for (Vec3& v : s.vertices) v = round_f(v - origin);
    s.center = round_f(s.center - origin);
    s.radius = static_cast<double>(static_cast<float>(s.radius));
    if (s.type == ShapeType::quad) {
      s.corner = s.vertices[0];
      s.edge_u = s.vertices[1] - s.vertices[0];
      s.edge_v = s.vertices[3] - s.vertices[0];
    }
  }
  for (DeltaLight& l : scene.delta_lights) {
    if (l.type == DeltaLightType::point) l.position = l.position - origin;
  }
  if (scene.camera) {
    scene.camera->position = scene.camera->position - origin;
    scene.camera->look_at = scene.camera->look_at - origin;
  }
}

}  // namespace tally
