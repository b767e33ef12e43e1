#include "common/sampling/sphere.hpp"

#include <cmath>

#include "common/sampling/disk.hpp"

namespace tally {
namespace {

Vec3 from_z_phi(double z, double sin_theta, double u_phi) {
  const double phi = 2.0 * kPi * u_phi;
  return {sin_theta * std::cos(phi), sin_theta * std::sin(phi), z};
}

}  // namespace

Vec3 sample_uniform_sphere(Vec2 u) {
  const double z = 1.0 - 2.0 * u.x;
  return from_z_phi(z, safe_sqrt(1.0 - z * z), u.y);
}

Vec2 invert_uniform_sphere(const Vec3& w) {
  return {clamp_unit(0.5 * (1.0 - w.z)), angle_to_unit(w.y, w.x)};
}

Vec3 sample_uniform_hemisphere(Vec2 u) {
  const double z = u.x;
  return from_z_phi(z, safe_sqrt(1.0 - z * z), u.y);
}

Vec2 invert_uniform_hemisphere(const Vec3& w) {
  return {clamp_unit(w.z), angle_to_unit(w.y, w.x)};
}

Vec3 sample_cosine_hemisphere(Vec2 u) {
  const DiskPolar d = sample_uniform_disk_concentric_polar(u);
  // z = sqrt(1 - r^2) formed as (1 - r)(1 + r): exact near the horizon, where 1 - x^2 - y^2
  // would leave only rounding noise of size sqrt(eps).
  return {d.r * std::cos(d.theta), d.r * std::sin(d.theta), safe_sqrt((1.0 - d.r) * (1.0 + d.r))};
}

Vec2 invert_cosine_hemisphere(const Vec3& w) {
  return invert_uniform_disk_concentric({w.x, w.y});
}

Vec3 sample_uniform_cone(Vec2 u, double cos_theta_max) {
  const double one_minus_cos = u.x * (1.0 - cos_theta_max);
  // sin^2 = (1 - cos)(1 + cos) avoids the cancellation in 1 - cos^2 near the axis.
  const double sin_theta = safe_sqrt(one_minus_cos * (2.0 - one_minus_cos));
  // max(): rounding must not put z an ulp outside the cone, where the pdf is 0.
  return from_z_phi(std::max(1.0 - one_minus_cos, cos_theta_max), sin_theta, u.y);
}

Vec2 invert_uniform_cone(const Vec3& w, double cos_theta_max) {
  const double sin2 = w.x * w.x + w.y * w.y;
  // 1 - cos = sin^2 / (1 + cos): exact near the axis where 1 - w.z cancels.
  const double one_minus_cos = w.z > 0 ? sin2 / (1.0 + w.z) : 1.0 - w.z;
  const double width = 1.0 - cos_theta_max;
  return {width > 0 ? clamp_unit(one_minus_cos / width) : 0.0, angle_to_unit(w.y, w.x)};
}

double uniform_cone_pdf(double cos_theta_max) {
  const double solid_angle = 2.0 * kPi * (1.0 - cos_theta_max);
  return solid_angle > 0 ? 1.0 / solid_angle : 0.0;
}

double uniform_cone_pdf(double cos_theta, double cos_theta_max) {
  return cos_theta >= cos_theta_max ? uniform_cone_pdf(cos_theta_max) : 0.0;
}

}  // namespace tally
