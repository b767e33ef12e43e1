// Jittered stratification: one point per stratum per sweep, uniform overall (chi-square),
// lower variance than plain MC, and overflow checks.
#include "common/sampling/stratified.hpp"

#include <cmath>
#include <set>
#include <stdexcept>
#include <vector>

#include <gtest/gtest.h>

#include "chi_square_support.hpp"

namespace tally {
namespace {

constexpr std::uint64_t kSeed = 0x57a7'1f1ed;

TEST(Stratified, UniformOverWholeSweeps) {
  // 1e6 samples = 15625 sweeps of the 8 x 8 strata.
  EXPECT_TRUE(test::passes_chi_square(test::chi_square_2d(
      {0, 1, 0, 1, 64, 64},
      [](std::uint64_t i) -> std::optional<Vec2> {
        SampleRng rng(stream_key(kSeed, 1), i);
        double p[2];
        stratified_sample(8, i, rng, p);
        return Vec2{p[0], p[1]};
      },
      [](Vec2) { return stratified_pdf(); })));
}

TEST(Stratified, OnePointPerStratumInsideItsCell) {
  constexpr std::uint32_t k = 5, s = 3;
  const std::uint64_t n = stratum_count(k, s);
  ASSERT_EQ(n, 125u);
  std::set<std::vector<int>> seen;
  for (std::uint64_t i = 0; i < n; ++i) {
    SampleRng rng(stream_key(kSeed, 2), i);
    double p[s];
    stratified_sample(k, i, rng, p);
    std::vector<int> cell;
    std::uint64_t rest = i;
    for (std::uint32_t d = 0; d < s; ++d) {
      ASSERT_TRUE(p[d] >= 0 && p[d] < 1);
      const auto c = static_cast<int>(rest % k);
      rest /= k;
      // The point lies in the stratum its index names (dimension 0 least significant).
      ASSERT_GE(p[d], c / static_cast<double>(k));
      ASSERT_LT(p[d], (c + 1) / static_cast<double>(k));
      cell.push_back(c);
    }
    seen.insert(cell);
  }
  EXPECT_EQ(seen.size(), n);
}

TEST(Stratified, EdgeJitterStaysInCell) {
  const double jitter[2] = {std::nextafter(1.0, 0.0), 0.0};
  double p[2];
  for (const std::uint32_t k : {3u, 7u, 10u, 49u, 1000u}) {
    const std::uint64_t last = stratum_count(k, 2) - 1;
    stratified_point(k, last, jitter, p);
    EXPECT_LT(p[0], 1.0) << k;
    EXPECT_GE(p[0], (k - 1.0) / k) << k;
    EXPECT_EQ(p[1], (k - 1.0) / k) << k;
  }
}

TEST(Stratified, VarianceBelowPlainMonteCarlo) {
  // f(x, y) = x * y with 16 x 16 strata and N = 256: the stratified estimator's variance
  // over 400 replicates must be well below plain MC's exact Var(f) / N.
  constexpr int kReplicates = 400;
  constexpr std::uint32_t k = 16;
  const std::uint64_t n = stratum_count(k, 2);
  double sum = 0, sum_sq_dev = 0;
  std::vector<double> estimates;
  for (int r = 0; r < kReplicates; ++r) {
    double acc = 0;
    for (std::uint64_t i = 0; i < n; ++i) {
      SampleRng rng(stream_key(kSeed, 100 + static_cast<std::uint64_t>(r)), i);
      double p[2];
      stratified_sample(k, i, rng, p);
      acc += p[0] * p[1];
    }
    estimates.push_back(acc / static_cast<double>(n));
    sum += estimates.back();
  }
  const double mean = sum / kReplicates;
  for (const double e : estimates) sum_sq_dev += (e - mean) * (e - mean);
  const double var_strat = sum_sq_dev / (kReplicates - 1);
  const double var_mc = (1.0 / 9.0 - 1.0 / 16.0) / static_cast<double>(n);
  EXPECT_LT(var_strat, var_mc / 20) << var_strat << " vs " << var_mc;
  EXPECT_NEAR(mean, 0.25, 4 * std::sqrt(var_strat / kReplicates));
}

TEST(Stratified, CountValidation) {
  EXPECT_THROW(stratum_count(0, 2), std::invalid_argument);
  EXPECT_THROW(stratum_count(2, 0), std::invalid_argument);
  EXPECT_THROW(stratum_count(2, 64), std::invalid_argument);
  EXPECT_EQ(stratum_count(2, 63), std::uint64_t{1} << 63);
}

}  // namespace
}  // namespace tally
