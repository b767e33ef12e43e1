#include "common/stats/tail_index.hpp"

#include <gtest/gtest.h>

#include <cmath>

#include "common/rng/counter_rng.hpp"

namespace tally {
namespace {

double hill_for(double (*f)(double), uint64_t n, uint64_t seed) {
  TailTracker t;
  const uint64_t key = stream_key(seed, 0);
  for (uint64_t i = 0; i < n; ++i) t.offer(std::fabs(f(SampleRng(key, i).open_uniform(0))));
  return t.hill_alpha(n).value_or(1e9);
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

TEST(TailIndex, BoundedAndLightTailsAreNotFlagged) {
  EXPECT_GT(hill_for([](double u) { return u; }, 1'000'000, 4), 10.0);
  EXPECT_GT(hill_for([](double u) { return -std::log(u); }, 1'000'000, 5), 4.0);  // exponential
  // Pareto alpha = 4: finite variance, must not warn.
  EXPECT_GT(hill_for([](double u) { return std::pow(u, -0.25); }, 1'000'000, 6), TailTracker::kWarnBelow);
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
