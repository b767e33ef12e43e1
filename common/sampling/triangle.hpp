#pragma once
// Uniform sampling of triangles. The 2-D map is Heitz's low-distortion square-to-triangle
// map (2019, as in pbrt-v4): area preserving like the classic sqrt map, but it keeps
// neighbouring samples together, which stratified and QMC points benefit from.
#include <array>

#include "common/math/vec3.hpp"

namespace tally {

// Barycentrics (b0, b1, b2), b_i >= 0, sum 1, uniform over the triangle.
std::array<double, 3> sample_uniform_triangle(Vec2 u);
Vec2 invert_uniform_triangle(const std::array<double, 3>& b);
// Density of (b0, b1) over the reference triangle {b0, b1 >= 0, b0 + b1 <= 1} (area 1/2).
constexpr double uniform_triangle_barycentric_pdf() {
  return 2.0;
}

double triangle_area(const Vec3& p0, const Vec3& p1, const Vec3& p2);

struct TrianglePointSample {
  Vec3 p;
  std::array<double, 3> b;
  double pdf;  // w.r.t. area: 1 / area, or 0 for a degenerate triangle (never inf or NaN)
};
// p = b0 p0 + b1 p1 + b2 p2.
TrianglePointSample sample_triangle_point(const Vec3& p0, const Vec3& p1, const Vec3& p2, Vec2 u);
double triangle_point_pdf(const Vec3& p0, const Vec3& p1, const Vec3& p2);

}  // namespace tally
