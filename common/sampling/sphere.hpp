#pragma once
// Directions on the unit sphere, hemisphere (z >= 0) and in a cone around +z, in a local
// frame (use Frame::to_world for a normal or a light axis). pdfs are w.r.t. solid angle.
#include "common/math/vec3.hpp"
#include "common/sampling/safe_math.hpp"

namespace tally {

// z = 1 - 2 u.x (Archimedes: equal z bands have equal area), phi = 2 pi u.y.
Vec3 sample_uniform_sphere(Vec2 u);
Vec2 invert_uniform_sphere(const Vec3& w);
constexpr double uniform_sphere_pdf() {
  return kInv4Pi;
}

// z = u.x in [0, 1), phi = 2 pi u.y.
Vec3 sample_uniform_hemisphere(Vec2 u);
Vec2 invert_uniform_hemisphere(const Vec3& w);
constexpr double uniform_hemisphere_pdf() {
  return kInv2Pi;
}

// Malley's method: a uniform point of the (concentric) disk lifted to the hemisphere has
// density cos(theta) / pi, the importance sampling the lecture derives for irradiance.
Vec3 sample_cosine_hemisphere(Vec2 u);
Vec2 invert_cosine_hemisphere(const Vec3& w);
inline double cosine_hemisphere_pdf(double cos_theta) {
  return std::max(cos_theta, 0.0) * kInvPi;
}

// Uniform in the cone cos(theta) >= cos_theta_max around +z (cos_theta_max in [-1, 1)),
// e.g. the directions subtended by a sphere light. Computed through 1 - cos(theta) so that
// small cones (cos_theta_max near 1) keep their precision.
Vec3 sample_uniform_cone(Vec2 u, double cos_theta_max);
Vec2 invert_uniform_cone(const Vec3& w, double cos_theta_max);
// Density inside the cone; 0 for a degenerate cone (cos_theta_max >= 1), which callers
// must treat as "no sample" rather than divide by.
double uniform_cone_pdf(double cos_theta_max);
// Density of direction with z = cos_theta: 0 outside the cone.
double uniform_cone_pdf(double cos_theta, double cos_theta_max);

}  // namespace tally
