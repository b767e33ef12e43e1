#pragma once
// The lighting scene as parsed from a job spec: camera, materials, shapes and the
// lights that are not shapes. Plain data; Embree and the estimators read it.
//
// Coordinates: the job compiler moves the scene into a local frame centred on its
// bounds (Scene::origin holds the world position of the local origin) and rounds every
// vertex to float there, so the geometry the estimators sample is exactly the geometry
// Embree traces, and a scene translated far from the world origin keeps full precision.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "common/lighting/texture.hpp"
#include "common/math/vec3.hpp"

namespace tally {

using Rgb = Vec3;

inline double luminance(const Rgb& c) { return 0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z; }
inline bool is_black(const Rgb& c) { return c.x == 0.0 && c.y == 0.0 && c.z == 0.0; }

enum class MaterialType { diffuse, emissive, mirror, phong, metallic_roughness };

// How a metallic-roughness material combines its diffuse base and its specular layer
// (bsdf.hpp, docs/lighting.md "Glossy materials"): glTF 2.0's reference (Appendix B,
// fresnel_mix with F(V.H)), the default for glTF files, or tally's energy-conserving
// form (the base weighted by (1 - F(cos_o)) (1 - F(cos_i))), the default for JSON
// materials. The scene's "material_model" field sets it for every one.
enum class MaterialModel { energy_conserving, gltf_reference };

struct Material {
  MaterialType type = MaterialType::diffuse;
  Rgb albedo{};       // Lambertian reflectance (diffuse; emissive may reflect too)
  Rgb emission{};     // emitted radiance (emissive)
  bool two_sided = false;  // emissive: emit from both faces
  Rgb reflectance{};  // mirror / phong specular reflectance
  double exponent = 0.0;  // phong (phong may also have a Lambertian `albedo`: OBJ Kd + Ks)
  // metallic_roughness (glTF's model, bsdf.hpp): GGX specular with F0 = lerp(0.04,
  // base_color, metallic) over a diffuse base_color (1 - metallic); roughness is glTF's
  // perceptual roughness, alpha = roughness^2. "ggx" in JSON is metallic 1.
  Rgb base_color{};
  double metallic = 0.0;
  double roughness = 1.0;
  MaterialModel model = MaterialModel::energy_conserving;
  // KHR_materials_specular: the dielectric's F0 = min(0.04 specular_color, 1) specular
  // and its F90 = specular (0: no specular layer, a pure Lambertian base).
  double specular = 1.0;
  Rgb specular_color{1, 1, 1};
  std::string name;
  // Image textures (indices into Scene::textures, -1: none), looked up at the hit's
  // texture coordinates by textured_material (texture.hpp), which multiplies them in.
  int32_t base_color_texture = -1;          // albedo or base_color x RGB (sRGB file)
  int32_t metallic_roughness_texture = -1;  // roughness x G, metallic x B (linear file)
  int32_t emission_texture = -1;            // emission x RGB (sRGB file)
  int32_t specular_color_texture = -1;      // specular_color x RGB (sRGB file)

  bool textured() const {
    return base_color_texture >= 0 || metallic_roughness_texture >= 0 || emission_texture >= 0 ||
           specular_color_texture >= 0;
  }
  // Any material may emit (glTF emissive materials reflect too); the JSON "emissive"
  // type is a Lambertian reflector with an emission.
  bool emits() const { return !is_black(emission); }
  bool is_delta() const { return type == MaterialType::mirror; }
  bool reflects() const {
    switch (type) {
      case MaterialType::mirror: return !is_black(reflectance);
      case MaterialType::phong: return !is_black(reflectance) || !is_black(albedo);
      case MaterialType::metallic_roughness: return !is_black(base_color) || metallic < 1.0;
      default: return !is_black(albedo);
    }
  }
};

enum class ShapeType { mesh, sphere, quad, disk };

struct Shape {
  ShapeType type = ShapeType::mesh;
  uint32_t material = 0;
  std::string pointer;  // JSON pointer of the shape in the spec, for messages
  // mesh and quad (a quad is also stored as its two triangles)
  std::vector<Vec3> vertices;
  std::vector<std::array<uint32_t, 3>> triangles;
  // sphere / disk
  Vec3 center{};
  double radius = 0.0;
  Vec3 normal{};  // disk
  // quad: corner + s * edge_u + t * edge_v, s, t in [0, 1]; normal edge_u x edge_v
  Vec3 corner{}, edge_u{}, edge_v{};
  // mesh: optional per-vertex shading normals (glTF NORMAL, OBJ vn; unit, in the same
  // order as vertices) and texture coordinates (glTF TEXCOORD_0). Empty = none: the
  // geometric normal shades.
  std::vector<Vec3> normals;
  std::vector<Vec2> uvs;

  // Convex shapes cannot shadow their own points; the planner relies on this.
  bool convex() const {
    return type != ShapeType::mesh || triangles.size() <= 1;
  }
};

enum class DeltaLightType { point, directional, spot };

struct DeltaLight {
  DeltaLightType type = DeltaLightType::point;
  Vec3 position{};   // point, spot
  Vec3 direction{};  // directional: unit vector from the scene towards the light;
                     // spot: unit axis of the cone, from the light outwards
  Rgb intensity{};   // point, spot: W/sr-like (radiant intensity on the axis); directional: irradiance
  // spot: glTF's smooth falloff between the cosines of the outer and inner cone angles
  // (KHR_lights_punctual): t = clamp((cos a - cos_outer) / max(1e-3, cos_inner - cos_outer), 0, 1),
  // intensity factor t^2, a the angle from the axis.
  double cos_inner = 1.0, cos_outer = 0.0;
};

// The spot light's factor for the unit direction `w` from the light towards a point.
inline double spot_falloff(const DeltaLight& l, const Vec3& w) {
  const double c = dot(l.direction, w);
  const double scale = 1.0 / std::max(1e-3, l.cos_inner - l.cos_outer);
  const double t = std::clamp((c - l.cos_outer) * scale, 0.0, 1.0);
  return t * t;
}

class EnvironmentMap;  // environment_map.hpp

struct Camera {
  Vec3 position{}, look_at{0, 0, -1}, up{0, 1, 0};
  double fov_deg = 45.0;  // vertical
  int width = 0, height = 0;
};

struct Scene {
  std::optional<Camera> camera;
  std::vector<Material> materials;
  std::vector<Shape> shapes;
  std::vector<DeltaLight> delta_lights;
  // The spec's "material_model", if given: the form of every metallic-roughness
  // material, including inline materials of query points.
  std::optional<MaterialModel> material_model;
  // The sky, at most one of: a constant radiance, or an environment map (immutable,
  // shared read-only by every thread of the job). A constant map arrives as `sky`.
  std::optional<Rgb> sky;
  std::shared_ptr<const EnvironmentMap> environment;
  // Textures the materials name; their texels are shared (a file used by several
  // textures is decoded once) and immutable (texture.hpp).
  std::vector<Texture> textures;
  uint64_t texture_bytes = 0;  // decoded texels of all textures, each grid counted once
  uint64_t decode_bytes = 0;   // what decoding the scene's images was charged (JobLimits::max_decode_bytes)
  Vec3 origin{};  // world position of the local origin (see above)
  size_t triangle_count() const {
    size_t n = 0;
    for (const Shape& s : shapes) n += s.triangles.size();
    return n;
  }
  // What the scene holds once compiled, estimated from its sizes (docs/performance.md):
  // per vertex 24 bytes (doubles) + 16 (Embree's floats), per triangle 12 + ~100 for the
  // BVH and light tables at their peak, normals 24, uvs 16, the textures' texels, and
  // 82 bytes an environment texel (its RGB and sampling tables).
  uint64_t resident_bytes() const;
  size_t vertex_count() const {
    size_t n = 0;
    for (const Shape& s : shapes) n += s.vertices.size();
    return n;
  }
};

}  // namespace tally
