// The lecture's two wrong samplers live only here, to prove the chi-square harness has
// the power to reject them against the correct pdf (p far below alpha'). If these ever
// pass, the harness has gone blind and every other chi-square test means nothing.
#include <cmath>
#include <cstdio>

#include <gtest/gtest.h>

#include "chi_square_support.hpp"
#include "common/rng/counter_rng.hpp"
#include "common/sampling/disk.hpp"

namespace tally {
namespace {

constexpr std::uint64_t kSeed = 0xbad'5a3b1e;
// "Far below": a million times smaller than the corrected per-test level.
constexpr double kFarBelow = 1e-6;

Vec2 u2(std::uint64_t stream, std::uint64_t index) {
  const SampleRng r(stream_key(kSeed, stream), index);
  return {r.uniform(0), r.uniform(1)};
}

// WRONG: r = xi is not equi-areal; it crowds the centre (density ~ 1 / r).
Vec2 disk_with_linear_radius(Vec2 u) {
  const double r = u.x, theta = 2 * kPi * u.y;
  return {r * std::cos(theta), r * std::sin(theta)};
}

// WRONG: normalising a point of the square over-weights the diagonals (the corners).
Vec2 direction_from_square(Vec2 u) {
  const double x = 1 - 2 * u.x, y = 1 - 2 * u.y;
  const double r = std::sqrt(x * x + y * y);
  return {x / r, y / r};
}

TEST(WrongMethods, LinearRadiusDiskIsRejected) {
  const test::ChiSquareResult r = test::chi_square_2d(
      {-1, 1, -1, 1, 64, 64},
      [](std::uint64_t i) { return std::optional(disk_with_linear_radius(u2(1, i))); },
      [](Vec2 p) { return p.x * p.x + p.y * p.y <= 1 + 1e-12 ? uniform_disk_pdf() : 0.0; });
  // The failure is the distribution, not a sample outside the support.
  EXPECT_EQ(r.outside, 0u);
  EXPECT_EQ(r.zero_pdf, 0u);
  EXPECT_TRUE(test::rejected_by_chi_square(r, kFarBelow));
  std::printf("  [wrong] %s\n", r.summary().c_str());
}

TEST(WrongMethods, NormalisedSquareDirectionIsRejected) {
  const test::ChiSquareResult r = test::chi_square_1d(
      -kPi, kPi, 101,
      [](std::uint64_t i) -> std::optional<double> {
        const Vec2 d = direction_from_square(u2(2, i));
        return std::atan2(d.y, d.x);
      },
      [](double) { return direction_2d_pdf(); });
  EXPECT_EQ(r.outside, 0u);
  EXPECT_TRUE(test::rejected_by_chi_square(r, kFarBelow));
  std::printf("  [wrong] %s\n", r.summary().c_str());
}

}  // namespace
}  // namespace tally
