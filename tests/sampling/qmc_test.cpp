// Owen-scrambled Sobol RQMC: the unscrambled points match Boost's Sobol generator, each
// randomization is unbiased (coordinate uniform over scrambles; mean of prod x_i), the
// net structure survives scrambling, and RQMC beats plain MC by a wide margin.
#include "common/sampling/qmc.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <stdexcept>
#include <vector>

#include <gtest/gtest.h>
#include <boost/random/sobol.hpp>

#include "chi_square_support.hpp"
#include "common/rng/counter_rng.hpp"

namespace tally {
namespace {

constexpr std::uint64_t kSeed = 0x0e4e'5cab;

TEST(Qmc, UnscrambledSobolMatchesBoost) {
  // Boost generates the same points in Gray-code order and skips the origin: its n-th
  // point (n = 1, 2, ...) is our point n ^ (n >> 1). This checks the direction numbers
  // and their recurrence for 64 dims.
  constexpr std::uint32_t kDims = 64;
  boost::random::sobol_engine<std::uint32_t, 32> engine(kDims);
  for (std::uint32_t n = 1; n <= 4096; ++n) {
    const std::uint32_t gray = n ^ (n >> 1);
    for (std::uint32_t d = 0; d < kDims; ++d) {
      ASSERT_EQ(engine(), sobol_bits(gray, d)) << "point " << n << " dim " << d;
    }
  }
}

TEST(Qmc, UnscrambledSobolMatchesBoostInAllDimensions) {
  boost::random::sobol_engine<std::uint32_t, 32> engine(kRqmcMaxDimensions);
  for (std::uint32_t n = 1; n <= 256; ++n) {
    for (std::uint32_t d = 0; d < kRqmcMaxDimensions; ++d) {
      ASSERT_EQ(engine(), sobol_bits(n ^ (n >> 1), d)) << "point " << n << " dim " << d;
    }
  }
}

TEST(Qmc, PointsAreInUnitIntervalAndDeterministic) {
  for (const std::uint64_t index :
       {std::uint64_t{0}, std::uint64_t{1}, std::uint64_t{12345}, (std::uint64_t{1} << 32) - 1,
        std::uint64_t{1} << 32, ~std::uint64_t{0}}) {
    for (const std::uint32_t dim : {0u, 1u, 7u, 63u, kRqmcMaxDimensions - 1}) {
      for (std::uint64_t seed = 0; seed < 50; ++seed) {
        const double x = rqmc_point(seed, index, dim);
        ASSERT_TRUE(x >= 0 && x < 1) << index << " " << dim << " " << seed;
        ASSERT_EQ(x, rqmc_point(seed, index, dim));
      }
    }
  }
  EXPECT_THROW(rqmc_point(1, 0, kRqmcMaxDimensions), std::out_of_range);
  EXPECT_THROW(sobol_bits(0, kRqmcMaxDimensions), std::out_of_range);
}

TEST(Qmc, CoordinateIsUniformOverScrambles) {
  // Unbiasedness of one randomization: for a fixed point and dimension, the coordinate
  // over independent scramble seeds is uniform on [0, 1).
  EXPECT_TRUE(test::passes_chi_square(test::chi_square_1d(
      0.0, 1.0, 101,
      [](std::uint64_t seed) -> std::optional<double> { return rqmc_point(seed, 12345, 5); },
      [](double) { return 1.0; })));
}

TEST(Qmc, OneScrambleFillsTheSquareUniformly) {
  // Many points of one randomization, dims 10 and 11: uniform (and far more even than
  // random points, so the p-value sits near 1).
  EXPECT_TRUE(test::passes_chi_square(test::chi_square_2d(
      {0, 1, 0, 1, 64, 64},
      [](std::uint64_t i) -> std::optional<Vec2> {
        return Vec2{rqmc_point(kSeed, i, 10), rqmc_point(kSeed, i, 11)};
      },
      [](Vec2) { return 1.0; })));
}

TEST(Qmc, ScramblingKeepsTheNetProperty) {
  // Each dimension of the first 2^10 points has exactly one point per interval of width
  // 2^-10, and each pair of dims 0 and 1 one point per 2^-5 x 2^-5 box ((0, m, 2)-net).
  for (std::uint64_t seed = 0; seed < 4; ++seed) {
    for (std::uint32_t dim = 0; dim < 16; ++dim) {
      std::vector<int> hits(1024, 0);
      for (std::uint64_t i = 0; i < 1024; ++i)
        ++hits[static_cast<std::size_t>(rqmc_point(seed, i, dim) * 1024)];
      ASSERT_EQ(std::count(hits.begin(), hits.end(), 1), 1024) << "seed " << seed << " dim " << dim;
    }
    std::vector<int> boxes(1024, 0);
    for (std::uint64_t i = 0; i < 1024; ++i) {
      const auto bx = static_cast<std::size_t>(rqmc_point(seed, i, 0) * 32);
      const auto by = static_cast<std::size_t>(rqmc_point(seed, i, 1) * 32);
      ++boxes[by * 32 + bx];
    }
    ASSERT_EQ(std::count(boxes.begin(), boxes.end(), 1), 1024) << "seed " << seed;
  }
}

struct Replicates {
  double mean, variance;  // of the per-randomization estimates
};

template <class F>
Replicates rqmc_replicates(int randomizations, std::uint64_t n, std::uint32_t dims, F f) {
  std::vector<double> x(dims);
  double mean = 0, m2 = 0;
  for (int r = 0; r < randomizations; ++r) {
    double acc = 0;
    for (std::uint64_t i = 0; i < n; ++i) {
      for (std::uint32_t d = 0; d < dims; ++d)
        x[d] = rqmc_point(kSeed + static_cast<std::uint64_t>(r), i, d);
      acc += f(x);
    }
    const double est = acc / static_cast<double>(n);
    const double delta = est - mean;
    mean += delta / (r + 1);
    m2 += delta * (est - mean);
  }
  return {mean, m2 / (randomizations - 1)};
}

double product(const std::vector<double>& x) {
  double p = 1;
  for (const double v : x) p *= v;
  return p;
}

TEST(Qmc, ProductMeanIsUnbiased) {
  // E[prod x_i] over [0,1]^4 = 1/16; small N per randomization so that the estimate's
  // spread is visible and the test has power against a biased scramble.
  constexpr int kRandomizations = 4000;
  const Replicates r = rqmc_replicates(kRandomizations, 16, 4, product);
  const double se = std::sqrt(r.variance / kRandomizations);
  EXPECT_GT(se, 0.0);
  EXPECT_NEAR(r.mean, 1.0 / 16.0, 4 * se) << "se " << se;
}

TEST(Qmc, VarianceFarBelowPlainMonteCarlo) {
  // Smooth f(x) = exp(x0 + x1 + x2 + x3) / (e - 1)^4 (mean 1). Plain MC at N = 1024 has
  // variance Var(f) / N exactly; Owen-scrambled Sobol should be orders of magnitude lower.
  constexpr std::uint64_t kN = 1024;
  const double e = std::exp(1.0);
  const double ef2 = std::pow((e * e - 1) / 2, 4) / std::pow(e - 1, 8);
  const double var_mc = (ef2 - 1.0) / static_cast<double>(kN);
  const Replicates r = rqmc_replicates(64, kN, 4, [&](const std::vector<double>& x) {
    return std::exp(x[0] + x[1] + x[2] + x[3]) / std::pow(e - 1, 4);
  });
  EXPECT_NEAR(r.mean, 1.0, 4 * std::sqrt(r.variance / 64) + 1e-12);
  std::printf("  RQMC variance reduction over MC at N = 1024: %.0fx\n", var_mc / r.variance);
  EXPECT_LT(r.variance, var_mc / 100)
      << "RQMC " << r.variance << " vs MC " << var_mc << " ratio " << var_mc / r.variance;
}

}  // namespace
}  // namespace tally
