// d-ball, (d-1)-sphere and d-simplex: chi-square of 2-D/1-D projections with known
// densities, invariants up to d = 64, volumes, uniform counts and validation.
#include "common/sampling/ball_simplex.hpp"

#include <cmath>
#include <numeric>
#include <stdexcept>
#include <vector>

#include <gtest/gtest.h>

#include "chi_square_support.hpp"
#include "common/sampling/safe_math.hpp"

namespace tally {
namespace {

using test::passes_chi_square;

constexpr std::uint64_t kSeed = 0xba11'5e7;

SampleRng rng_for(std::uint64_t stream, std::uint64_t index) {
  return SampleRng(stream_key(kSeed, stream), index);
}

std::vector<double> ball(std::uint32_t d, std::uint64_t stream, std::uint64_t i) {
  std::vector<double> x(d);
  SampleRng rng = rng_for(stream, i);
  sample_uniform_ball(rng, x);
  return x;
}
std::vector<double> sphere(std::uint32_t d, std::uint64_t stream, std::uint64_t i) {
  std::vector<double> x(d);
  SampleRng rng = rng_for(stream, i);
  sample_uniform_sphere_surface(rng, x);
  return x;
}
std::vector<double> simplex(std::uint32_t d, std::uint64_t stream, std::uint64_t i) {
  std::vector<double> x(d);
  SampleRng rng = rng_for(stream, i);
  sample_uniform_simplex(rng, x);
  return x;
}
double norm2(const std::vector<double>& x) {
  return std::inner_product(x.begin(), x.end(), x.begin(), 0.0);
}

TEST(Ball, Disk2DIsUniform) {
  EXPECT_TRUE(passes_chi_square(test::chi_square_2d(
      {-1, 1, -1, 1, 64, 64},
      [](std::uint64_t i) -> std::optional<Vec2> {
        const std::vector<double> x = ball(2, 1, i);
        return Vec2{x[0], x[1]};
      },
      [](Vec2 p) { return p.x * p.x + p.y * p.y <= 1 + 1e-12 ? uniform_ball_pdf(2) : 0.0; })));
}

TEST(Ball, Ball3DRadiusAndPolarAngle) {
  // Uniform in the 3-ball <=> r^3 uniform on [0, 1] and cos(polar) uniform on [-1, 1],
  // independent: density 1/2 over (r^3, z / r).
  EXPECT_TRUE(passes_chi_square(test::chi_square_2d(
      {0, 1, -1, 1, 40, 80},
      [](std::uint64_t i) -> std::optional<Vec2> {
        const std::vector<double> x = ball(3, 2, i);
        const double r = std::sqrt(norm2(x));
        if (!(r > 0)) return std::nullopt;
        return Vec2{r * r * r, x[2] / r};
      },
      [](Vec2) { return 0.5; })));
}

TEST(Ball, Ball7DRadius) {
  EXPECT_TRUE(passes_chi_square(test::chi_square_1d(
      0, 1, 101,
      [](std::uint64_t i) -> std::optional<double> { return std::pow(norm2(ball(7, 3, i)), 3.5); },
      [](double) { return 1.0; })));
}

TEST(SphereSurface, S2IsUniform) {
  EXPECT_TRUE(passes_chi_square(test::chi_square_2d(
      {-1, 1, -kPi, kPi, 80, 160},
      [](std::uint64_t i) -> std::optional<Vec2> {
        const std::vector<double> x = sphere(3, 4, i);
        if (std::abs(norm2(x) - 1) > 1e-12) return std::nullopt;
        return Vec2{x[2], std::atan2(x[1], x[0])};
      },
      [](Vec2) { return uniform_sphere_surface_pdf(3); })));
}

TEST(SphereSurface, S1IsUniform) {
  EXPECT_TRUE(passes_chi_square(test::chi_square_1d(
      -kPi, kPi, 101,
      [](std::uint64_t i) -> std::optional<double> {
        const std::vector<double> x = sphere(2, 5, i);
        if (std::abs(norm2(x) - 1) > 1e-12) return std::nullopt;
        return std::atan2(x[1], x[0]);
      },
      [](double) { return uniform_sphere_surface_pdf(2); })));
}

TEST(Simplex, Triangle2DIsUniform) {
  EXPECT_TRUE(passes_chi_square(test::chi_square_2d(
      {0, 1, 0, 1, 64, 64},
      [](std::uint64_t i) -> std::optional<Vec2> {
        const std::vector<double> x = simplex(2, 6, i);
        return Vec2{x[0], x[1]};
      },
      [](Vec2 p) {
        return p.x >= 0 && p.y >= 0 && p.x + p.y <= 1 + 1e-12 ? uniform_simplex_pdf(2) : 0.0;
      })));
}

TEST(Simplex, Tetrahedron3DProjection) {
  // Marginal of (x0, x1) for the uniform 3-simplex (density 6): 6 (1 - x0 - x1).
  EXPECT_TRUE(passes_chi_square(test::chi_square_2d(
      {0, 1, 0, 1, 64, 64},
      [](std::uint64_t i) -> std::optional<Vec2> {
        const std::vector<double> x = simplex(3, 7, i);
        return Vec2{x[0], x[1]};
      },
      [](Vec2 p) {
        const double rest = 1 - p.x - p.y;
        return p.x >= 0 && p.y >= 0 && rest >= 0 ? 6 * rest : 0.0;
      })));
}

TEST(Simplex, Marginal10D) {
  // One coordinate of the uniform 10-simplex is Beta(1, 10): 10 (1 - x)^9.
  EXPECT_TRUE(passes_chi_square(test::chi_square_1d(
      0, 1, 101, [](std::uint64_t i) -> std::optional<double> { return simplex(10, 8, i)[3]; },
      [](double x) { return x >= 0 && x <= 1 ? 10 * std::pow(1 - x, 9) : 0.0; })));
}

TEST(BallSimplex, InvariantsUpTo64Dimensions) {
  for (std::uint32_t d = 1; d <= kMaxBallSimplexDim; ++d) {
    for (std::uint64_t i = 0; i < 200; ++i) {
      const std::vector<double> b = ball(d, 9, i), s = sphere(d, 10, i), x = simplex(d, 11, i);
      ASSERT_LE(norm2(b), 1.0 + 1e-12) << d;
      ASSERT_NEAR(norm2(s), 1.0, 1e-12) << d;
      double sum = 0;
      for (const double xi : x) {
        ASSERT_GE(xi, 0.0) << d;
        sum += xi;
      }
      ASSERT_LE(sum, 1.0 + 1e-12) << d;
      for (const double v : b) ASSERT_TRUE(std::isfinite(v));
    }
  }
}

TEST(Ball, Moments64D) {
  // In the unit d-ball E[|x|^2] = d / (d + 2); checked within 4 sigma of the sample mean.
  constexpr std::uint32_t d = 64;
  constexpr int n = 20'000;
  double mean = 0, m2 = 0;
  for (int i = 0; i < n; ++i) {
    const double v = norm2(ball(d, 12, static_cast<std::uint64_t>(i)));
    const double delta = v - mean;
    mean += delta / (i + 1);
    m2 += delta * (v - mean);
  }
  const double se = std::sqrt(m2 / (n - 1) / n);
  EXPECT_NEAR(mean, d / (d + 2.0), 4 * se);
}

TEST(BallSimplex, Volumes) {
  EXPECT_DOUBLE_EQ(unit_ball_volume(1), 2.0);
  EXPECT_DOUBLE_EQ(unit_ball_volume(2), kPi);
  EXPECT_DOUBLE_EQ(unit_ball_volume(3), 4.0 * kPi / 3.0);
  EXPECT_DOUBLE_EQ(sphere_surface_area(2), 2.0 * kPi);
  EXPECT_DOUBLE_EQ(sphere_surface_area(3), 4.0 * kPi);
  EXPECT_DOUBLE_EQ(simplex_volume(3), 1.0 / 6.0);
  for (std::uint32_t d = 1; d <= 64; ++d) {
    const double half = d / 2.0;
    EXPECT_NEAR(unit_ball_volume(d) / (std::pow(kPi, half) / std::tgamma(half + 1)), 1.0, 1e-12)
        << d;
    EXPECT_NEAR(simplex_volume(d) * std::tgamma(d + 1.0), 1.0, 1e-12) << d;
  }
}

TEST(BallSimplex, FixedUniformCountsAndValidation) {
  for (const std::uint32_t d : {1u, 2u, 3u, 7u, 64u}) {
    std::vector<double> x(d);
    SampleRng a = rng_for(13, 0), b = rng_for(13, 0), c = rng_for(13, 0);
    sample_uniform_ball(a, x);
    sample_uniform_sphere_surface(b, x);
    sample_uniform_simplex(c, x);
    EXPECT_EQ(a.dims_used(), ball_uniform_count(d));
    EXPECT_EQ(b.dims_used(), sphere_surface_uniform_count(d));
    EXPECT_EQ(c.dims_used(), simplex_uniform_count(d));
  }
  std::vector<double> x(3), u(2);
  EXPECT_THROW(sample_uniform_ball(u, x), std::invalid_argument);
  std::vector<double> big(65);
  SampleRng rng = rng_for(14, 0);
  EXPECT_THROW(sample_uniform_simplex(rng, big), std::invalid_argument);
  std::vector<double> none;
  EXPECT_THROW(sample_uniform_sphere_surface(rng, none), std::invalid_argument);
  // All-zero uniforms: no 0/0, a valid point comes out.
  std::vector<double> zeros(simplex_uniform_count(3), 0.0), y(3);
  sample_uniform_simplex(zeros, y);
  for (const double v : y) EXPECT_EQ(v, 0.0);
  std::vector<double> zs(sphere_surface_uniform_count(3), 0.0), w(3);
  sample_uniform_sphere_surface(zs, w);
  EXPECT_NEAR(norm2(w), 1.0, 1e-15);
}

}  // namespace
}  // namespace tally
