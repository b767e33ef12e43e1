#include "common/lighting/obj_scene.hpp"

#include <fmt/format.h>
#include <tiny_obj_loader.h>

#include <algorithm>
#include <charconv>
#include <cmath>
#include <map>
#include <set>
#include <string_view>

#include "common/lighting/texture.hpp"
#include "common/spec/spec_reader.hpp"
#include "common/sampling/safe_math.hpp"

namespace tally {

namespace {

constexpr double kCoordLimit = 1e12;

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
  Texture tex;
  uint64_t charged = 0;
  try {
    tex.texels = decode_texels(bytes, srgb, texture_decode_limits(scene, limits), &charged);
  } catch (const std::exception& e) {
    throw SpecError(pointer, fmt::format("{}: cannot be used as a texture: {}", what, e.what()));
  }
  tex.wrap_s = tex.wrap_t = o.clamp ? TextureWrap::clamp_to_edge : TextureWrap::repeat;
  scene.texture_bytes += tex.texels->bytes();
  scene.decode_bytes += charged;
  if (scene.textures.size() >= 4096) throw SpecError(pointer, "too many textures (limit 4096)");
  scene.textures.push_back(std::move(tex));
  return static_cast<int32_t>(scene.textures.size() - 1);
}

// The lines of a text in order, numbered from 1 (the pre-scans' error messages name them).
struct Lines {
  std::string_view text;
  size_t pos = 0, number = 0;
  bool next(std::string_view& line) {
    if (pos >= text.size()) return false;
    size_t end = text.find('\n', pos);
    if (end == std::string_view::npos) end = text.size();
    line = text.substr(pos, end - pos);
    pos = end + 1;
    ++number;
    return true;
  }
};

// What the pre-scan found: the counts tinyobjloader will allocate for, all checked.
struct ObjCensus {
  size_t vertices = 0, texcoords = 0, normals = 0, triangles = 0;
  std::vector<std::string> mtllibs;  // the files `mtllib` lines name (a line may name several)
};

// One pass over the OBJ text before tinyobjloader sees it. tinyobjloader reads "nan" and
// out-of-range integers without complaint and triangulates a polygon in time quadratic
// in its corners; here every v / vt / vn number must be finite and within 1e12, every
// face corner a non-zero integer index naming an element already given (negative:
// relative), a face has 3 to max_polygon_vertices corners, and the file's vertices,
// triangles (with the scene's so far) and material groups are within the limits.
ObjCensus scan_obj(std::string_view text, const std::string& file, const std::string& pointer, const JobLimits& limits,
                   size_t triangles_so_far) {
  ObjCensus c;
  std::set<std::string_view> materials;
  Lines lines{text};
  auto fail = [&](const std::string& what) {
    return SpecError(pointer, fmt::format("OBJ \"{}\" line {}: {}", file, lines.number, what));
  };
  auto tokens_of = [](std::string_view line) {
    std::vector<std::string_view> out;
    size_t i = 0;
    while (i < line.size()) {
      const size_t b = line.find_first_not_of(" \t\r", i);
      if (b == std::string_view::npos) break;
      const size_t e = std::min(line.find_first_of(" \t\r", b), line.size());
      out.push_back(line.substr(b, e - b));
      i = e;
    }
    return out;
  };
  auto numbers = [&](const std::vector<std::string_view>& t, size_t min, size_t& count) {
    if (t.size() - 1 < min) throw fail(fmt::format("\"{}\" needs at least {} numbers", t[0], min));
    for (size_t k = 1; k < t.size(); ++k) {
      double x = 0;
      const auto r = std::from_chars(t[k].data(), t[k].data() + t[k].size(), x);
      if (r.ec != std::errc() || r.ptr != t[k].data() + t[k].size() || !std::isfinite(x) || std::fabs(x) > kCoordLimit) {
        throw fail(fmt::format("\"{}\" is not a finite number within 1e12", t[k]));
      }
    }
    ++count;
  };
  // One index of a face corner: a non-zero integer naming one of the `have` elements.
  auto index = [&](std::string_view s, size_t have, const char* what) {
    int64_t x = 0;
    const auto r = std::from_chars(s.data(), s.data() + s.size(), x);
    if (r.ec != std::errc() || r.ptr != s.data() + s.size() || x == 0 ||
        (x > 0 ? static_cast<uint64_t>(x) > have : x < -static_cast<int64_t>(std::min<size_t>(have, INT64_MAX)))) {
      throw fail(fmt::format("{} index \"{}\" names none of the {} given so far", what, s, have));
    }
  };
  for (std::string_view line; lines.next(line);) {
    if (line.find_first_not_of(" \t\r") == std::string_view::npos) continue;
    const std::vector<std::string_view> t = tokens_of(line);
    const std::string_view kind = t[0];
    if (kind == "v") {
      numbers(t, 3, c.vertices);
      if (c.vertices > limits.max_vertices) {
        throw fail(fmt::format("more than {} vertices in the file (max_vertices)", limits.max_vertices));
      }
    } else if (kind == "vt") {
      numbers(t, 1, c.texcoords);
      if (c.texcoords > limits.max_vertices) {
        throw fail(fmt::format("more than {} texture coordinates in the file (max_vertices)", limits.max_vertices));
      }
    } else if (kind == "vn") {
      numbers(t, 3, c.normals);
      if (c.normals > limits.max_vertices) {
        throw fail(fmt::format("more than {} normals in the file (max_vertices)", limits.max_vertices));
      }
    } else if (kind == "f") {
      const size_t corners = t.size() - 1;
      if (corners < 3) throw fail("a face needs at least 3 corners");
      if (corners > limits.max_polygon_vertices) {
        throw fail(fmt::format("a face of {} corners, more than the limit of {} (max_polygon_vertices)", corners,
                               limits.max_polygon_vertices));
      }
      for (size_t k = 1; k < t.size(); ++k) {
        const std::string_view corner = t[k];
        const size_t s1 = corner.find('/');
        index(corner.substr(0, s1), c.vertices, "vertex");
        if (s1 == std::string_view::npos) continue;
        const size_t s2 = corner.find('/', s1 + 1);
        const std::string_view vt = corner.substr(s1 + 1, s2 == std::string_view::npos ? std::string_view::npos : s2 - s1 - 1);
        if (!vt.empty()) index(vt, c.texcoords, "texture coordinate");
        if (s2 != std::string_view::npos) index(corner.substr(s2 + 1), c.normals, "normal");
      }
      c.triangles += corners - 2;
      if (triangles_so_far + c.triangles > limits.max_triangles) {
        throw fail(fmt::format("more than {} triangles in the scene (max_triangles)", limits.max_triangles));
      }
    } else if (kind == "mtllib") {
      for (size_t k = 1; k < t.size(); ++k) c.mtllibs.emplace_back(t[k]);
    } else if (kind == "usemtl") {
      materials.insert(t.size() > 1 ? t[1] : std::string_view());
      if (materials.size() > limits.max_shapes) {
        throw fail(fmt::format("more than {} materials used, each a shape (max_shapes)", limits.max_shapes));
      }
    }
  }
  return c;
}

// An OBJ's .mtl libraries hold at most as many materials as a scene may (4096), in at
// most 2^18 lines that are neither blank nor comments (a real library has ~10 a material).
constexpr size_t kMaxMtlMaterials = 4096;
constexpr size_t kMaxMtlLines = size_t{1} << 18;

// One pass over an .mtl library before tinyobjloader sees it, counting into `materials`
// and `lines` (all the OBJ's libraries together). tinyobjloader makes a material_t of
// ~1.9 KB for each `newmtl` line however short ("newmtl a": 9 bytes, a 200-fold growth),
// and keeps each unknown keyword line in a map node of the current material.
void scan_mtl(std::string_view text, const std::string& file, const std::string& pointer, size_t& materials,
              size_t& counted) {
  Lines lines{text};
  for (std::string_view line; lines.next(line);) {
    const size_t b = line.find_first_not_of(" \t\r");
    if (b == std::string_view::npos || line[b] == '#') continue;
    auto fail = [&](const std::string& what) {
      return SpecError(pointer, fmt::format(".mtl \"{}\" line {}: {}", file, lines.number, what));
    };
    if (++counted > kMaxMtlLines) throw fail(fmt::format("more than {} lines in the OBJ's .mtl libraries", kMaxMtlLines));
    const std::string_view rest = line.substr(b);
    if (rest.substr(0, 6) == "newmtl" && (rest.size() == 6 || rest[6] == ' ' || rest[6] == '\t')) {
      if (++materials > kMaxMtlMaterials) {
        throw fail(fmt::format("more than {} materials in the OBJ's .mtl libraries", kMaxMtlMaterials));
      }
    }
  }
}

// The vertices `tris` use, ascending, and `tris` renumbered into them.
std::vector<uint32_t> compact(std::vector<std::array<uint32_t, 3>>& tris) {
  std::vector<uint32_t> used;
  used.reserve(3 * tris.size());
  for (const auto& t : tris) used.insert(used.end(), t.begin(), t.end());
  std::sort(used.begin(), used.end());
  used.erase(std::unique(used.begin(), used.end()), used.end());
  for (auto& t : tris) {
    for (uint32_t& v : t) v = static_cast<uint32_t>(std::lower_bound(used.begin(), used.end(), v) - used.begin());
  }
  return used;
}

}  // namespace

std::vector<Shape> load_obj(const std::string& relative, const std::string& pointer, const AssetReader& read,
                            const JobLimits& limits, std::optional<uint32_t> material, Scene& scene) {
  tinyobj::ObjReaderConfig config;
  config.triangulate = true;
  config.vertex_color = false;
  const std::string text = read(relative, pointer);
  const size_t triangles_so_far = scene.triangle_count();
  size_t vertices_so_far = scene.vertex_count();
  const ObjCensus census = scan_obj(text, relative, pointer, limits, triangles_so_far);
  const auto slash = relative.find_last_of('/');
  const std::string dir = slash == std::string::npos ? std::string() : relative.substr(0, slash + 1);
  std::string mtl_text;
  if (!material) {
    // Each library once, however often `mtllib` lines name it (naming one 1 MB library
    // 10,000 times on one line made a 10 GB text).
    std::set<std::string> read_already;
    size_t materials = 0, lines = 0;
    for (const std::string& lib : census.mtllibs) {
      if (!read_already.insert(lib).second) continue;
      const std::string library = read(dir + lib, pointer);
      scan_mtl(library, lib, pointer, materials, lines);
      mtl_text += library + "\n";
    }
  }
  tinyobj::ObjReader reader;
  if (!reader.ParseFromString(text, mtl_text, config)) {
    throw SpecError(pointer, fmt::format("cannot read OBJ: {}", reader.Error()));
  }
  const auto& attrib = reader.GetAttrib();
  const size_t nv = attrib.vertices.size() / 3;
  auto vertex = [&](size_t i) {
    return Vec3{static_cast<double>(attrib.vertices[3 * i]), static_cast<double>(attrib.vertices[3 * i + 1]),
                static_cast<double>(attrib.vertices[3 * i + 2])};
  };
  // Faces grouped by OBJ material (-1: none), in order of first use.
  std::vector<int> group_ids;
  std::map<int, size_t> group_of;
  std::vector<std::vector<std::array<uint32_t, 3>>> groups;
  std::vector<std::vector<std::array<int, 3>>> group_vt;  // vt indices of the same faces (-1: none)
  const size_t nvt = attrib.texcoords.size() / 2;
  size_t total = 0;
  for (const auto& shape : reader.GetShapes()) {
    const auto& idx = shape.mesh.indices;
    if (triangles_so_far + total + idx.size() / 3 > limits.max_triangles) {
      throw SpecError(pointer, fmt::format("too many triangles (limit {}, max_triangles)", limits.max_triangles));
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
      auto [it, fresh] = group_of.emplace(mid, groups.size());
      if (fresh) {
        if (groups.size() >= limits.max_shapes) {
          throw SpecError(pointer, fmt::format("more than {} material groups (max_shapes)", limits.max_shapes));
        }
        group_ids.push_back(mid);
        groups.emplace_back();
        group_vt.emplace_back();
      }
      groups[it->second].push_back(t);
      group_vt[it->second].push_back(vt);
      ++total;
    }
  }
  if (total == 0) throw SpecError(pointer, "OBJ file has no triangles");
  const auto& mats = reader.GetMaterials();
  std::vector<Shape> out;
  auto charge_vertices = [&](size_t n) {
    if (vertices_so_far + n > limits.max_vertices) {
      throw SpecError(pointer, fmt::format("{} more vertices, more than the limit of {} in the scene (max_vertices)", n,
                                           limits.max_vertices));
    }
    vertices_so_far += n;
  };
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
            charge_vertices(1);
            s.vertices.push_back(vertex(key.first));
            s.uvs.push_back({static_cast<double>(attrib.texcoords[2 * static_cast<size_t>(ti)]),
                             1.0 - static_cast<double>(attrib.texcoords[2 * static_cast<size_t>(ti) + 1])});
          }
          groups[g][f][k] = it->second;
        }
      }
    } else {
      // Only the vertices this group's faces use (64 groups of a 2M-vertex file kept a
      // copy of all of them each).
      const std::vector<uint32_t> used = compact(groups[g]);
      charge_vertices(used.size());
      s.vertices.resize(used.size());
      for (size_t i = 0; i < used.size(); ++i) s.vertices[i] = vertex(used[i]);
    }
    for (const Vec3& v : s.vertices) {
      for (int c = 0; c < 3; ++c) {
        if (!std::isfinite(v[c]) || std::fabs(v[c]) > kCoordLimit) {
          throw SpecError(pointer, "OBJ vertex is not finite or out of range");
        }
      }
    }
    for (const Vec2& uv : s.uvs) {
      if (!std::isfinite(uv.x) || !std::isfinite(uv.y)) throw SpecError(pointer, "OBJ texture coordinates must be finite");
    }
    s.triangles = std::move(groups[g]);
    groups[g].clear();
    group_vt[g].clear();
    out.push_back(std::move(s));
  }
  return out;
}

}  // namespace tally
