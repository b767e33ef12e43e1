// Triangle sampling: chi-square of the barycentrics, inverse round trip, the 3-D point
// helper's pdf including degenerate triangles (pdf 0, never NaN or inf).
#include "common/sampling/triangle.hpp"

#include <cmath>
#include <limits>

#include <gtest/gtest.h>

#include "chi_square_support.hpp"
#include "common/rng/counter_rng.hpp"

namespace tally {
namespace {

constexpr std::uint64_t kSeed = 0x7121'a261e;

Vec2 u2(std::uint64_t stream, std::uint64_t index) {
  const SampleRng r(stream_key(kSeed, stream), index);
  return {r.uniform(0), r.uniform(1)};
}

TEST(Triangle, BarycentricsAreUniform) {
  EXPECT_TRUE(test::passes_chi_square(test::chi_square_2d(
      {0.0, 1.0, 0.0, 1.0, 64, 64},
      [](std::uint64_t i) -> std::optional<Vec2> {
        const std::array<double, 3> b = sample_uniform_triangle(u2(1, i));
        if (std::abs(b[0] + b[1] + b[2] - 1.0) > 1e-12 || b[2] < 0) return std::nullopt;
        return Vec2{b[0], b[1]};
      },
      [](Vec2 p) {
        return p.x >= 0 && p.y >= 0 && p.x + p.y <= 1.0 + 1e-12 ? uniform_triangle_barycentric_pdf()
                                                                : 0.0;
      })));
}

TEST(Triangle, RoundTrip) {
  for (const double a : test::unit_test_grid(101)) {
    for (const double b : test::unit_test_grid(101)) {
      const std::array<double, 3> bary = sample_uniform_triangle({a, b});
      for (const double bi : bary)
        ASSERT_TRUE(bi >= 0 && bi <= 1 && std::isfinite(bi)) << a << " " << b;
      const Vec2 v = invert_uniform_triangle(bary);
      ASSERT_TRUE(v.x >= 0 && v.x < 1 && v.y >= 0 && v.y < 1) << a << " " << b;
      EXPECT_NEAR(v.x, a, 1e-6) << a << " " << b;
      EXPECT_NEAR(v.y, b, 1e-6) << a << " " << b;
    }
  }
}

TEST(Triangle, PointOnTriangleIn3D) {
  const Vec3 p0{1, 0, 0}, p1{0, 2, 0}, p2{0, 0, 3};
  const double area = 0.5 * length(cross(p1 - p0, p2 - p0));
  EXPECT_DOUBLE_EQ(triangle_area(p0, p1, p2), area);
  for (std::uint64_t i = 0; i < 1000; ++i) {
    const TrianglePointSample s = sample_triangle_point(p0, p1, p2, u2(2, i));
    EXPECT_DOUBLE_EQ(s.pdf, 1.0 / area);
    // On the plane x + y/2 + z/3 = 1, inside the triangle.
    EXPECT_NEAR(s.p.x + s.p.y / 2 + s.p.z / 3, 1.0, 1e-12);
    EXPECT_TRUE(s.p.x >= 0 && s.p.y >= 0 && s.p.z >= -1e-15);
    const Vec3 q = p0 * s.b[0] + p1 * s.b[1] + p2 * s.b[2];
    EXPECT_NEAR(length(q - s.p), 0.0, 1e-15);
  }
}

TEST(Triangle, DegenerateTrianglesHaveZeroPdf) {
  const Vec3 a{1, 2, 3};
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  // Coincident vertices, collinear vertices, non-finite vertices.
  EXPECT_EQ(triangle_point_pdf(a, a, a), 0.0);
  EXPECT_EQ(triangle_point_pdf(a, {2, 4, 6}, {3, 6, 9}), 0.0);
  EXPECT_EQ(triangle_point_pdf(a, {nan, 0, 0}, {0, 1, 0}), 0.0);
  EXPECT_EQ(triangle_point_pdf(a, {inf, 0, 0}, {0, 1, 0}), 0.0);
  const TrianglePointSample s = sample_triangle_point(a, a, a, {0.3, 0.9});
  EXPECT_EQ(s.pdf, 0.0);
  EXPECT_NEAR(length(s.p - a), 0.0, 1e-15);
  // A tiny but valid triangle still has a finite positive pdf.
  const double tiny_pdf = triangle_point_pdf({0, 0, 0}, {1e-150, 0, 0}, {0, 1e-150, 0});
  EXPECT_TRUE(std::isfinite(tiny_pdf) && tiny_pdf > 0) << tiny_pdf;
}

}  // namespace
}  // namespace tally
