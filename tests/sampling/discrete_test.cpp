// DiscreteCdf and AliasTable: chi-square against the normalised weights, zero weights
// never sampled, the remapped uniform is uniform, and input validation.
#include <cmath>
#include <limits>
#include <stdexcept>
#include <vector>

#include <gtest/gtest.h>

#include "chi_square_support.hpp"
#include "common/rng/counter_rng.hpp"
#include "common/sampling/alias_table.hpp"
#include "common/sampling/discrete_cdf.hpp"

namespace tally {
namespace {

using test::passes_chi_square;

constexpr std::uint64_t kSeed = 0xd15c'7e7e;

double uniform(std::uint64_t stream, std::uint64_t index) {
  return SampleRng(stream_key(kSeed, stream), index).uniform(0);
}

// Non-uniform, with zeros at the ends and in the middle, one dominant and some tiny
// entries (expected counts below 5 exercise the pooling).
const std::vector<double> kWeights = {0.0, 3.0, 1.0,  0.5,  0.0, 0.0,  7.5, 2e-6, 4.0,  0.25,
                                      1.0, 0.0, 12.0, 3e-6, 2.0, 0.75, 0.0, 5.0,  1e-6, 0.0};

std::vector<double> normalized(const std::vector<double>& w) {
  double total = 0;
  for (const double x : w) total += x;
  std::vector<double> p;
  for (const double x : w) p.push_back(x / total);
  return p;
}

TEST(DiscreteCdf, MatchesWeights) {
  const DiscreteCdf cdf(kWeights);
  EXPECT_TRUE(passes_chi_square(test::chi_square_discrete(
      normalized(kWeights), [&](std::uint64_t i) { return cdf.sample(uniform(1, i)); })));
}

TEST(AliasTable, MatchesWeights) {
  const AliasTable alias(kWeights);
  EXPECT_TRUE(passes_chi_square(test::chi_square_discrete(
      normalized(kWeights), [&](std::uint64_t i) { return alias.sample(uniform(2, i)); })));
}

TEST(DiscreteCdf, RemappedUniformIsUniform) {
  // The reused uniform must be uniform on [0, 1) whatever index came out (else a point
  // placed with it inside the chosen cell would be biased).
  const DiscreteCdf cdf(kWeights);
  EXPECT_TRUE(passes_chi_square(test::chi_square_1d(
      0.0, 1.0, 101,
      [&](std::uint64_t i) -> std::optional<double> {
        double r = -1;
        cdf.sample_remapped(uniform(3, i), &r);
        return r;
      },
      [](double) { return 1.0; })));
}

TEST(DiscreteCdf, PdfAndEdges) {
  const DiscreteCdf cdf(kWeights);
  const std::vector<double> p = normalized(kWeights);
  double sum = 0;
  for (std::size_t i = 0; i < kWeights.size(); ++i) {
    EXPECT_NEAR(cdf.pdf(i), p[i], 1e-15);
    sum += cdf.pdf(i);
  }
  EXPECT_NEAR(sum, 1.0, 1e-12);
  EXPECT_EQ(cdf.pdf(kWeights.size()), 0.0);
  EXPECT_EQ(cdf.cdf(kWeights.size()), 1.0);
  // u = 0 and the largest u below 1 land on the first and last positive entries.
  EXPECT_EQ(cdf.sample(0.0), 1u);
  EXPECT_EQ(cdf.sample(std::nextafter(1.0, 0.0)), 18u);
  double r = -1;
  EXPECT_EQ(cdf.sample_remapped(std::nextafter(1.0, 0.0), &r), 18u);
  EXPECT_TRUE(r >= 0 && r < 1);
  const AliasTable alias(kWeights);
  for (const double u : test::unit_test_grid(100'001)) {
    ASSERT_GT(kWeights[cdf.sample(u)], 0) << u;
    ASSERT_GT(kWeights[alias.sample(u)], 0) << u;
    ASSERT_EQ(alias.pdf(alias.sample(u)), cdf.pdf(alias.sample(u)));
  }
}

TEST(DiscreteCdf, HugeWeightsDoNotOverflow) {
  const std::vector<double> w = {1e308, 1e308, 0.0, 1e308};
  const DiscreteCdf cdf(w);
  const AliasTable alias(w);
  EXPECT_NEAR(cdf.pdf(0), 1.0 / 3, 1e-15);
  EXPECT_NEAR(alias.pdf(3), 1.0 / 3, 1e-15);
  EXPECT_EQ(cdf.sample(0.5), 1u);
}

TEST(DiscreteCdf, SingleEntry) {
  const std::vector<double> w = {0.0, 2.0, 0.0};
  const DiscreteCdf cdf(w);
  const AliasTable alias(w);
  for (const double u : test::unit_test_grid(101)) {
    EXPECT_EQ(cdf.sample(u), 1u);
    EXPECT_EQ(alias.sample(u), 1u);
  }
}

template <class Distribution>
void expect_rejects(const std::vector<double>& w, const char* needle) {
  try {
    Distribution d(w);
    ADD_FAILURE() << "accepted invalid weights, expected: " << needle;
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
  }
}

TEST(DiscreteCdf, RejectsInvalidWeights) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  for (const auto& check : {expect_rejects<DiscreteCdf>, expect_rejects<AliasTable>}) {
    check({1.0, -0.5, 2.0}, "weight[1]");
    check({1.0, nan}, "weight[1]");
    check({inf, 1.0}, "weight[0]");
    check({0.0, 0.0, 0.0}, "all weights are zero");
    check({}, "no weights");
  }
}

}  // namespace
}  // namespace tally
