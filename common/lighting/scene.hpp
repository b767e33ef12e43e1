#pragma once
// The lighting scene as parsed from a job spec: camera, materials, shapes and the
// lights that are not shapes. Plain data; Embree and the estimators read it.
//
// Coordinates: the job compiler moves the scene into a local frame centred on its
// bounds (Scene::origin holds the world position of the local origin) and rounds every
// vertex to float there, so the geometry the estimators sample is exactly the geometry
// Embree traces, and a scene translated far from the world origin keeps full precision.
#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "common/math/vec3.hpp"

namespace tally {

using Rgb = Vec3;

inline double luminance(const Rgb& c) { return 0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z; }
inline bool is_black(const Rgb& c) { return c.x == 0.0 && c.y == 0.0 && c.z == 0.0; }

enum class MaterialType { diffuse, emissive, mirror, phong };

struct Material {
  MaterialType type = MaterialType::diffuse;
  Rgb albedo{};       // Lambertian reflectance (diffuse; emissive may reflect too)
  Rgb emission{};     // emitted radiance (emissive)
  bool two_sided = false;  // emissive: emit from both faces
  Rgb reflectance{};  // mirror / phong specular reflectance
  double exponent = 0.0;  // phong
  std::string name;

  bool emits() const { return type == MaterialType::emissive && !is_black(emission); }
  bool is_delta() const { return type == MaterialType::mirror; }
  bool reflects() const {
    return type == MaterialType::mirror || type == MaterialType::phong ? !is_black(reflectance)
                                                                        : !is_black(albedo);
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

  // Convex shapes cannot shadow their own points; the planner relies on this.
  bool convex() const {
    return type != ShapeType::mesh || triangles.size() <= 1;
  }
};

enum class DeltaLightType { point, directional };

struct DeltaLight {
  DeltaLightType type = DeltaLightType::point;
  Vec3 position{};   // point
  Vec3 direction{};  // directional: unit vector from the scene towards the light
  Rgb intensity{};   // point: W/sr-like (radiant intensity); directional: irradiance
};

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
  std::optional<Rgb> sky;
  Vec3 origin{};  // world position of the local origin (see above)
  size_t triangle_count() const {
    size_t n = 0;
    for (const Shape& s : shapes) n += s.triangles.size();
    return n;
  }
};

}  // namespace tally
