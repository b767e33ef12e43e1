#include "common/stats/tally.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "common/rng/counter_rng.hpp"
#include "common/stats/confidence.hpp"

namespace tally {
namespace {

std::vector<double> uniform_plus(double offset, size_t n, uint64_t seed) {
  std::vector<double> v(n);
  const uint64_t key = stream_key(seed, 0);
  for (size_t i = 0; i < n; ++i) v[i] = offset + SampleRng(key, i).uniform(0);
  return v;
}

// The numerics checklist's hard case: the naive E[x^2] - E[x]^2 gives -23,085 for
// U(0,1) + 1e9 in double; Welford and the two-pass batch keep 1/12.
TEST(Tally, WelfordKeepsVarianceOfLargeOffsetSamples) {
  const auto v = uniform_plus(1e9, 1'000'000, 1);
  Tally t;
  for (double x : v) t.add(x);
  // The sample variance of 10^6 uniforms is itself within ~0.3% of 1/12; compare to the
  // exact sample variance computed from the offset-free values in long double.
  long double s = 0, s2 = 0;
  for (double x : v) {
    const long double y = static_cast<long double>(x) - 1e9L;
    s += y;
  }
  const long double m = s / v.size();
  for (double x : v) {
    const long double y = static_cast<long double>(x) - 1e9L - m;
    s2 += y * y;
  }
  const double exact = static_cast<double>(s2 / (v.size() - 1));
  // Each x carries the rounding of 1e9 + u (ulp 1.2e-7), a variance change of ~1e-15.
  EXPECT_NEAR(t.variance(), exact, 1e-6 * exact);
  EXPECT_NEAR(t.variance(), 1.0 / 12.0, 0.01 / 12.0);
  const Tally b = Tally::from_batch(v.data(), v.size());
  EXPECT_NEAR(b.variance(), exact, 1e-6 * exact);
}

TEST(Tally, MergedPartialsEqualOnePass) {
  const auto v = uniform_plus(3.0, 100'000, 2);
  Tally one;
  for (double x : v) one.add(x);
  // Uneven partitions merged in order.
  Tally merged;
  size_t pos = 0;
  for (size_t len : {1, 7, 4096, 33333, 12345}) {
    merged.merge(Tally::from_batch(v.data() + pos, len));
    pos += len;
  }
  merged.merge(Tally::from_batch(v.data() + pos, v.size() - pos));
  EXPECT_EQ(merged.n, one.n);
  EXPECT_NEAR(merged.mean, one.mean, 1e-12 * one.mean);
  EXPECT_NEAR(merged.m2, one.m2, 1e-10 * one.m2);
}

TEST(Tally, MergeWithEmptyIsIdentity) {
  Tally a;
  a.add(1.0);
  a.add(3.0);
  Tally b = a;
  b.merge(Tally{});
  EXPECT_EQ(a, b);
  Tally c;
  c.merge(a);
  EXPECT_EQ(a, c);
}

// Long runs must not stall: float accumulation stops at 2^24; 10^9 samples merged
// block by block keep the count exact and the mean correct.
TEST(Tally, LongRunDoesNotStall) {
  std::vector<double> block(1000);
  for (size_t i = 0; i < block.size(); ++i) block[i] = (i % 2 == 0) ? 1.0 : 3.0;
  const Tally bt = Tally::from_batch(block.data(), block.size());
  Tally t;
  for (int i = 0; i < 1'000'000; ++i) t.merge(bt);
  EXPECT_EQ(t.n, 1'000'000'000ULL);
  EXPECT_NEAR(t.mean, 2.0, 1e-12);
  EXPECT_NEAR(t.variance(), 1.0 * 1e9 / (1e9 - 1), 1e-9);
}

TEST(Tally, SingleSampleHasNoVariance) {
  Tally t;
  t.add(5.0);
  EXPECT_TRUE(std::isnan(t.variance()));
  EXPECT_TRUE(std::isnan(t.std_error()));
}

TEST(Confidence, StudentTAndNormalCriticalValues) {
  EXPECT_NEAR(critical_value(0.95, 10), 2.262157163, 1e-8);  // t_{0.975, 9}
  EXPECT_NEAR(critical_value(0.99, 5), 4.604094871, 1e-8);   // t_{0.995, 4}
  EXPECT_NEAR(critical_value(0.95, 10'000'000), 1.959963985, 1e-8);
  EXPECT_TRUE(std::isinf(critical_value(0.95, 1)));
}

TEST(Confidence, IntervalIsSymmetricAroundMean) {
  Tally t;
  for (double x : {1.0, 2.0, 3.0, 4.0}) t.add(x);
  const Interval ci = confidence_interval(t, 0.95);
  EXPECT_NEAR(0.5 * (ci.lo + ci.hi), 2.5, 1e-15);
  // s = sqrt(5/3), t_{0.975,3} = 3.182446305
  EXPECT_NEAR(ci.hi - 2.5, 3.182446305 * std::sqrt(5.0 / 3.0) / 2.0, 1e-8);
}

TEST(Confidence, SamplesForHalfWidth) {
  // (1.96 * 2 / 0.01)^2 = 153,658.6
  EXPECT_NEAR(samples_for_half_width(2.0, 0.01, 0.95), 153658.6, 1.0);
}

}  // namespace
}  // namespace tally
