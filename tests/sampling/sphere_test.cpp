// Sphere, hemisphere, cosine-hemisphere and cone samplers: chi-square over (z, phi)
// (dz dphi is exactly solid angle, so the histogram needs no Jacobian), pdf values and
// inverse round trips.
#include "common/sampling/sphere.hpp"

#include <cmath>
#include <functional>

#include <gtest/gtest.h>

#include "chi_square_support.hpp"
#include "common/rng/counter_rng.hpp"

namespace tally {
namespace {

using test::chi_square_2d;
using test::passes_chi_square;

constexpr std::uint64_t kSeed = 0x5eed'5afe;

Vec2 u2(std::uint64_t stream, std::uint64_t index) {
  const SampleRng r(stream_key(kSeed, stream), index);
  return {r.uniform(0), r.uniform(1)};
}

// A direction as a (z, phi) histogram point; not a unit vector -> a counted failure.
std::optional<Vec2> z_phi(const Vec3& w) {
  if (!(std::abs(length(w) - 1.0) <= 1e-12)) return std::nullopt;
  return Vec2{w.z, std::atan2(w.y, w.x)};
}

const test::Histogram2D kFullSphere{-1.0, 1.0, -kPi, kPi, 80, 160};

test::ChiSquareResult direction_chi_square(const test::Histogram2D& h, std::uint64_t stream,
                                           const std::function<Vec3(Vec2)>& sample,
                                           const std::function<double(double z)>& pdf_of_z) {
  return chi_square_2d(
      h, [&](std::uint64_t i) { return z_phi(sample(u2(stream, i))); },
      [&](Vec2 p) { return pdf_of_z(p.x); });
}

TEST(Sphere, UniformSphere) {
  EXPECT_TRUE(passes_chi_square(direction_chi_square(kFullSphere, 1, sample_uniform_sphere,
                                                     [](double) { return uniform_sphere_pdf(); })));
}

TEST(Sphere, UniformHemisphere) {
  EXPECT_TRUE(passes_chi_square(
      direction_chi_square(kFullSphere, 2, sample_uniform_hemisphere,
                           [](double z) { return z >= 0 ? uniform_hemisphere_pdf() : 0.0; })));
}

TEST(Sphere, CosineHemisphere) {
  EXPECT_TRUE(passes_chi_square(
      direction_chi_square(kFullSphere, 3, sample_cosine_hemisphere, cosine_hemisphere_pdf)));
}

TEST(Sphere, WideCone) {
  constexpr double kCosMax = 0.3;  // on a cell edge of the 80 z cells
  EXPECT_TRUE(passes_chi_square(direction_chi_square(
      kFullSphere, 4, [](Vec2 u) { return sample_uniform_cone(u, kCosMax); },
      [](double z) { return uniform_cone_pdf(z, kCosMax); })));
}

TEST(Sphere, NarrowCone) {
  // A small cone gets its own fine histogram near the pole; half the z range lies outside.
  constexpr double kCosMax = 0.95;
  EXPECT_TRUE(passes_chi_square(direction_chi_square(
      {0.9, 1.0, -kPi, kPi, 40, 80}, 5, [](Vec2 u) { return sample_uniform_cone(u, kCosMax); },
      [](double z) { return uniform_cone_pdf(z, kCosMax); })));
}

TEST(Sphere, PdfValues) {
  EXPECT_DOUBLE_EQ(uniform_sphere_pdf(), 1.0 / (4.0 * kPi));
  EXPECT_DOUBLE_EQ(uniform_hemisphere_pdf(), 1.0 / (2.0 * kPi));
  EXPECT_DOUBLE_EQ(cosine_hemisphere_pdf(1.0), 1.0 / kPi);
  EXPECT_EQ(cosine_hemisphere_pdf(-0.5), 0.0);
  EXPECT_DOUBLE_EQ(uniform_cone_pdf(0.0), uniform_hemisphere_pdf());
  EXPECT_DOUBLE_EQ(uniform_cone_pdf(-1.0), uniform_sphere_pdf());
  EXPECT_EQ(uniform_cone_pdf(0.2, 0.5), 0.0);
  // A degenerate cone has no density: 0, never inf.
  EXPECT_EQ(uniform_cone_pdf(1.0), 0.0);
  const Vec3 axis = sample_uniform_cone({0.3, 0.7}, 1.0);
  EXPECT_EQ(axis.z, 1.0);
}

TEST(Sphere, TinyConeKeepsPrecision) {
  // cos_theta_max = 1 - 1e-12: 1 - cos^2 would lose all digits; the 1 - cos path keeps
  // the angle right and the inverse exact.
  const double cos_max = 1.0 - 1e-12;
  const Vec3 w = sample_uniform_cone({0.25, 0.1}, cos_max);
  const double sin_theta = std::hypot(w.x, w.y);
  const double omc = 0.25 * (1.0 - cos_max);
  EXPECT_NEAR(sin_theta, std::sqrt(omc * (2 - omc)), 1e-20);
  const Vec2 u = invert_uniform_cone(w, cos_max);
  EXPECT_NEAR(u.x, 0.25, 1e-6);
  EXPECT_NEAR(u.y, 0.1, 1e-9);
}

struct Warp {
  std::function<Vec3(Vec2)> forward;
  std::function<Vec2(const Vec3&)> inverse;
  std::function<double(const Vec3&)> pdf;
  bool periodic_phi;  // u.y -> phi = 2 pi u.y: 0 and 1 are the same direction
  double z_min;       // directions must satisfy z >= z_min; pdf > 0 where z > z_min
};

void expect_round_trip(const Warp& warp) {
  for (const double a : test::unit_test_grid(101)) {
    for (const double b : test::unit_test_grid(101)) {
      const Vec3 w = warp.forward({a, b});
      ASSERT_TRUE(std::isfinite(w.x) && std::isfinite(w.y) && std::isfinite(w.z)) << a << " " << b;
      ASSERT_NEAR(length(w), 1.0, 1e-12) << a << " " << b;
      ASSERT_GE(w.z, warp.z_min) << a << " " << b;
      const double pdf = warp.pdf(w);
      ASSERT_TRUE(std::isfinite(pdf) && pdf >= 0) << a << " " << b;
      if (w.z > warp.z_min) {
        ASSERT_GT(pdf, 0) << a << " " << b;
      }
      const Vec2 v = warp.inverse(w);
      ASSERT_TRUE(v.x >= 0 && v.x < 1 && v.y >= 0 && v.y < 1) << a << " " << b;
      const Vec3 w2 = warp.forward(v);
      // 1e-7, not 1e-9: at the horizon z = sqrt((1 - r)(1 + r)) moves by sqrt(ulp) ~ 1e-8
      // when u moves by one ulp, so a perfect inverse can still differ there.
      EXPECT_NEAR(length(w2 - w), 0.0, 1e-7) << a << " " << b;
      if (std::hypot(w.x, w.y) < 1e-12) continue;  // at a pole phi is arbitrary
      EXPECT_NEAR(v.x, a, 1e-6) << a << " " << b;
      const double dy = warp.periodic_phi ? std::remainder(v.y - b, 1.0) : v.y - b;
      EXPECT_NEAR(dy, 0.0, 1e-6) << a << " " << b;
    }
  }
}

TEST(Sphere, RoundTrips) {
  expect_round_trip({sample_uniform_sphere, invert_uniform_sphere,
                     [](const Vec3&) { return uniform_sphere_pdf(); }, true, -1.0});
  expect_round_trip({sample_uniform_hemisphere, invert_uniform_hemisphere,
                     [](const Vec3&) { return uniform_hemisphere_pdf(); }, true, 0.0});
  expect_round_trip({sample_cosine_hemisphere, invert_cosine_hemisphere,
                     [](const Vec3& w) { return cosine_hemisphere_pdf(w.z); }, false, 0.0});
  for (const double cos_max : {-0.7, 0.0, 0.3, 0.95, 1.0 - 1e-9}) {
    expect_round_trip({[=](Vec2 u) { return sample_uniform_cone(u, cos_max); },
                       [=](const Vec3& w) { return invert_uniform_cone(w, cos_max); },
                       [=](const Vec3& w) { return uniform_cone_pdf(w.z, cos_max); }, true,
                       cos_max});
  }
}

}  // namespace
}  // namespace tally
