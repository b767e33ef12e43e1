#include "common/sampling/triangle.hpp"

#include <cmath>

#include "common/sampling/safe_math.hpp"

namespace tally {

std::array<double, 3> sample_uniform_triangle(Vec2 u) {
  double b0, b1;
  // Heitz 2019: shear the half of the square above / below the diagonal onto the triangle.
  if (u.x < u.y) {
    b0 = u.x / 2;
    b1 = u.y - b0;
  } else {
    b1 = u.y / 2;
    b0 = u.x - b1;
  }
  return {b0, b1, std::max(0.0, 1.0 - b0 - b1)};
}

Vec2 invert_uniform_triangle(const std::array<double, 3>& b) {
  if (b[0] > b[1]) return {clamp_unit(b[0] + b[1]), clamp_unit(2 * b[1])};
  return {clamp_unit(2 * b[0]), clamp_unit(b[1] + b[0])};
}

double triangle_area(const Vec3& p0, const Vec3& p1, const Vec3& p2) {
  // hypot, not sqrt(dot): squaring the cross product would underflow to 0 for triangles
  // with sides near 1e-150 that still have a representable area.
  const Vec3 n = cross(p1 - p0, p2 - p0);
  return 0.5 * std::hypot(n.x, n.y, n.z);
}

double triangle_point_pdf(const Vec3& p0, const Vec3& p1, const Vec3& p2) {
  const double area = triangle_area(p0, p1, p2);
  // Zero-area (or non-finite) triangles have no area density; 0 tells callers to skip.
  return (area > 0 && std::isfinite(area)) ? 1.0 / area : 0.0;
}

TrianglePointSample sample_triangle_point(const Vec3& p0, const Vec3& p1, const Vec3& p2, Vec2 u) {
  const std::array<double, 3> b = sample_uniform_triangle(u);
  return {p0 * b[0] + p1 * b[1] + p2 * b[2], b, triangle_point_pdf(p0, p1, p2)};
}

}  // namespace tally
