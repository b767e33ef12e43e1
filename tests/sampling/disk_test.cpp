// Uniform disk and 2-D direction samplers: chi-square against the uniform pdf, inverse
// round trips, and the rejection sampler's acceptance rate.
#include "common/sampling/disk.hpp"

#include <cmath>

#include <gtest/gtest.h>

#include "chi_square_support.hpp"

namespace tally {
namespace {

using test::chi_square_1d;
using test::chi_square_2d;
using test::passes_chi_square;

constexpr std::uint64_t kSeed = 0x5eed'd15c;

SampleRng rng_for(std::uint64_t stream, std::uint64_t index) {
  return SampleRng(stream_key(kSeed, stream), index);
}
Vec2 u2(std::uint64_t stream, std::uint64_t index) {
  const SampleRng r = rng_for(stream, index);
  return {r.uniform(0), r.uniform(1)};
}

// Uniform over the unit disk, in Cartesian coordinates. The 1e-12 slack admits points
// that rounding put an ulp outside the circle (cos^2 + sin^2 can exceed 1 by an ulp).
double disk_pdf(Vec2 p) {
  return p.x * p.x + p.y * p.y <= 1.0 + 1e-12 ? uniform_disk_pdf() : 0.0;
}
const test::Histogram2D kDiskHistogram{-1.0, 1.0, -1.0, 1.0, 64, 64};

TEST(Disk, PolarIsUniform) {
  EXPECT_TRUE(passes_chi_square(chi_square_2d(
      kDiskHistogram,
      [](std::uint64_t i) { return std::optional(sample_uniform_disk_polar(u2(1, i))); },
      disk_pdf)));
}

TEST(Disk, ConcentricIsUniform) {
  EXPECT_TRUE(passes_chi_square(chi_square_2d(
      kDiskHistogram,
      [](std::uint64_t i) { return std::optional(sample_uniform_disk_concentric(u2(2, i))); },
      disk_pdf)));
}

TEST(Disk, RejectionIsUniform) {
  RejectionStats stats;
  EXPECT_TRUE(passes_chi_square(chi_square_2d(
      kDiskHistogram,
      [&](std::uint64_t i) {
        SampleRng rng = rng_for(3, i);
        return sample_uniform_disk_rejection(rng, 64, stats);
      },
      disk_pdf)));
}

TEST(Disk, RejectionAcceptanceRateIsPiOver4) {
  RejectionStats stats;
  constexpr std::uint64_t kSamples = 200'000;
  for (std::uint64_t i = 0; i < kSamples; ++i) {
    SampleRng rng = rng_for(4, i);
    ASSERT_TRUE(sample_uniform_disk_rejection(rng, 64, stats).has_value());
  }
  // Every attempt is a Bernoulli(pi/4) trial: 4 binomial sigmas over `attempts` trials.
  const double p = kPi / 4;
  const double sigma = std::sqrt(p * (1 - p) / static_cast<double>(stats.attempts));
  EXPECT_EQ(stats.accepted, kSamples);
  EXPECT_NEAR(stats.acceptance_rate(), p, 4 * sigma) << "attempts = " << stats.attempts;
}

TEST(Disk, RejectionCapReturnsNulloptAndCounts) {
  RejectionStats stats;
  SampleRng rng = rng_for(5, 0);
  // A cap of 0 attempts can never accept: the caller sees a counted failure, not a hang.
  EXPECT_FALSE(sample_uniform_disk_rejection(rng, 0, stats).has_value());
  EXPECT_EQ(stats.attempts, 0u);
  EXPECT_EQ(stats.acceptance_rate(), 0.0);
  // Rejections are counted: a proposal that never accepts uses exactly the cap.
  const auto never = rejection_sample(rng, 17, stats, [](SampleRng& r) -> std::optional<int> {
    (void)r.next();
    return std::nullopt;
  });
  EXPECT_FALSE(never.has_value());
  EXPECT_EQ(stats.attempts, 17u);
  EXPECT_EQ(stats.accepted, 0u);
  EXPECT_EQ(rng.dims_used(), 17u);
}

double angle_of(Vec2 d) {
  return std::atan2(d.y, d.x);
}
// Uniform angle in (-pi, pi]; a direction must also have unit length.
double direction_pdf(double) {
  return direction_2d_pdf();
}

TEST(Direction2D, AnalyticIsUniform) {
  EXPECT_TRUE(passes_chi_square(chi_square_1d(
      -kPi, kPi, 101,
      [](std::uint64_t i) -> std::optional<double> {
        const Vec2 d = sample_direction_2d(rng_for(6, i).uniform(0));
        if (std::abs(std::hypot(d.x, d.y) - 1.0) > 1e-12) return std::nullopt;
        return angle_of(d);
      },
      direction_pdf)));
}

TEST(Direction2D, RejectionIsUniform) {
  RejectionStats stats;
  EXPECT_TRUE(passes_chi_square(chi_square_1d(
      -kPi, kPi, 101,
      [&](std::uint64_t i) -> std::optional<double> {
        SampleRng rng = rng_for(7, i);
        const std::optional<Vec2> d = sample_direction_2d_rejection(rng, 64, stats);
        if (!d || std::abs(std::hypot(d->x, d->y) - 1.0) > 1e-12) return std::nullopt;
        return angle_of(*d);
      },
      direction_pdf)));
}

// inverse(forward(u)) == u on a grid including 0 and the largest double below 1. Where
// the map is not injective (the centre of the disk), only forward(inverse(p)) == p is
// required.
template <class Forward, class Inverse>
void expect_disk_round_trip(Forward forward, Inverse inverse) {
  for (const double a : test::unit_test_grid(101)) {
    for (const double b : test::unit_test_grid(101)) {
      const Vec2 u{a, b};
      const Vec2 p = forward(u);
      ASSERT_TRUE(std::isfinite(p.x) && std::isfinite(p.y)) << a << " " << b;
      ASSERT_LE(p.x * p.x + p.y * p.y, 1.0 + 1e-12) << a << " " << b;
      const Vec2 v = inverse(p);
      ASSERT_TRUE(v.x >= 0 && v.x < 1 && v.y >= 0 && v.y < 1) << a << " " << b;
      const Vec2 q = forward(v);
      EXPECT_NEAR(q.x, p.x, 1e-9) << a << " " << b;
      EXPECT_NEAR(q.y, p.y, 1e-9) << a << " " << b;
      if (p.x * p.x + p.y * p.y > 1e-20) {
        // u.y near 1 and near 0 give the same angle: compare on the circle.
        EXPECT_NEAR(v.x, u.x, 1e-6) << a << " " << b;
        const double dy = std::remainder(v.y - u.y, 1.0);
        EXPECT_NEAR(dy, 0.0, 1e-6) << a << " " << b;
      }
    }
  }
}

TEST(Disk, PolarRoundTrip) {
  expect_disk_round_trip(sample_uniform_disk_polar, invert_uniform_disk_polar);
}

TEST(Disk, ConcentricRoundTrip) {
  // The concentric map is injective everywhere except at the centre; its angle is not
  // periodic in u, so the comparison must be exact, not modulo 1.
  for (const double a : test::unit_test_grid(101)) {
    for (const double b : test::unit_test_grid(101)) {
      const Vec2 p = sample_uniform_disk_concentric({a, b});
      const Vec2 v = invert_uniform_disk_concentric(p);
      ASSERT_TRUE(v.x >= 0 && v.x < 1 && v.y >= 0 && v.y < 1) << a << " " << b;
      if (p.x * p.x + p.y * p.y > 1e-20) {
        EXPECT_NEAR(v.x, a, 1e-6) << a << " " << b;
        EXPECT_NEAR(v.y, b, 1e-6) << a << " " << b;
      }
    }
  }
  expect_disk_round_trip(sample_uniform_disk_concentric, invert_uniform_disk_concentric);
}

TEST(Direction2D, RoundTrip) {
  for (const double u : test::unit_test_grid(1001)) {
    const Vec2 d = sample_direction_2d(u);
    ASSERT_NEAR(std::hypot(d.x, d.y), 1.0, 1e-15);
    const double v = invert_direction_2d(d);
    ASSERT_TRUE(v >= 0 && v < 1) << u;
    EXPECT_NEAR(std::remainder(v - u, 1.0), 0.0, 1e-6) << u;
  }
}

}  // namespace
}  // namespace tally
