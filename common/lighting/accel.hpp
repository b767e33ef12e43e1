#pragma once
// The scene in Embree: one geometry per shape (geomID = shape index). Triangle meshes
// and quads are Embree triangles; spheres and disks are user geometries intersected in
// double precision. Built and committed once per job, then shared read-only by every
// worker (rtcIntersect1/rtcOccluded1 are thread-safe on a committed scene).
#include <embree3/rtcore.h>

#include <cstdint>
#include <optional>

#include "common/lighting/scene.hpp"

namespace tally {

struct Hit {
  double t = 0.0;
  Vec3 p{};  // hit point in local coordinates, recomputed in double on the surface
  Vec3 n{};  // unit geometric normal of the shape (outward / winding side)
  uint32_t shape = 0;
  uint32_t prim = 0;
  bool has_ns = false;  // meshes with vertex normals
  Vec3 ns{};            // unit interpolated shading normal (the vertex normals' side)
  Vec2 uv{};            // interpolated texture coordinates (meshes with uvs)
};

class Accel {
 public:
  // `scene` must outlive the Accel and must not move (user geometries point into it).
  // Throws std::runtime_error on Embree errors.
  explicit Accel(const Scene& scene);
  ~Accel();
  Accel(const Accel&) = delete;
  Accel& operator=(const Accel&) = delete;

  // Closest hit along o + t d, t in (0, t_max). `o` should already be offset.
  std::optional<Hit> intersect(const Vec3& o, const Vec3& d, double t_max) const;
  // Any hit along o + t d, t in (0, t_max).
  bool occluded(const Vec3& o, const Vec3& d, double t_max) const;

 private:
  const Scene& scene_;
  RTCScene rtc_ = nullptr;
};

}  // namespace tally
