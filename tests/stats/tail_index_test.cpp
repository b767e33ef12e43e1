#include "common/stats/tail_index.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <optional>

#include "common/rng/counter_rng.hpp"

namespace tally {
namespace {

// The Hill estimate of |f(U)|'s tail; 1e6 samples always give one (k = 511), and a
// missing estimate fails the test (issue 27: a default of 1e9 passed every "not flagged").
double hill_for(double (*f)(double), uint64_t n, uint64_t seed) {
  TailTracker t;
  const uint64_t key = stream_key(seed, 0);
  for (uint64_t i = 0; i < n; ++i) t.offer(std::fabs(f(SampleRng(key, i).open_uniform(0))));
  const std::optional<double> alpha = t.hill_alpha(n);
  EXPECT_TRUE(alpha.has_value()) << "no tail estimate from " << n << " samples";
  return alpha.value_or(std::numeric_limits<double>::quiet_NaN());  // NaN fails every comparison
}

// 1/sqrt(U) is Pareto with alpha = 2 exactly. k = 511 top values: the Hill
// estimate's sd is alpha/sqrt(k) ~ 0.09, so +-0.35 is a ~4 sigma bound.
TEST(TailIndex, ParetoTwoIsDetected) {
  for (uint64_t seed : {1, 2, 3}) {
    const double a = hill_for([](double u) { return 1.0 / std::sqrt(u); }, 1'000'000, seed);
    EXPECT_NEAR(a, 2.0, 0.35) << seed;
    EXPECT_LT(a, TailTracker::kWarnBelow) << seed;
  }
}

// Bounded and light tails have large (or, for a bounded f, growing) Hill estimates; the
// Pareto alpha = 4 one is near 4 (sd ~ 4 / sqrt(511) = 0.18: +-1 is > 5 sd).
TEST(TailIndex, BoundedAndLightTailsAreNotFlagged) {
  EXPECT_GT(hill_for([](double u) { return u; }, 1'000'000, 4), 10.0);
  const double expo = hill_for([](double u) { return -std::log(u); }, 1'000'000, 5);  // exponential
  EXPECT_GT(expo, 4.0);
  EXPECT_LT(expo, 1e3);  // a finite estimate, not a sentinel
  // Pareto alpha = 4: finite variance, must not warn.
  const double pareto4 = hill_for([](double u) { return std::pow(u, -0.25); }, 1'000'000, 6);
  EXPECT_GT(pareto4, TailTracker::kWarnBelow);
  EXPECT_NEAR(pareto4, 4.0, 1.0);
}

TEST(TailIndex, TooFewSamplesGiveNoEstimate) {
  TailTracker t;
  for (int i = 1; i <= 50; ++i) t.offer(i);
  EXPECT_FALSE(t.hill_alpha(50).has_value());
}

TEST(TailIndex, MergeKeepsLargest) {
  TailTracker a(4), b(4);
  for (double v : {1.0, 5.0, 3.0}) a.offer(v);
  for (double v : {4.0, 2.0, 6.0}) b.offer(v);
  a.merge(b);
  EXPECT_EQ(a.sorted_values(), (std::vector<double>{6.0, 5.0, 4.0, 3.0}));
}

}  // namespace
}  // namespace tally
