// The shuffled Owen-scrambled 2-D Sobol' sequence of the image sampler: its unscrambled
// dimensions are Sobol's (checked against the Joe-Kuo table of qmc.cpp), every aligned
// block of 2^m points of every pair is a (0, m, 2)-net for every seed, a coordinate is
// uniform over seeds, and the nested scramble is a bijection that keeps prefixes.
#include "common/sampling/sobol_burley.hpp"

#include <algorithm>
#include <cmath>
#include <vector>

#include <boost/math/distributions/chi_squared.hpp>
#include <gtest/gtest.h>

#include "common/lighting/pixel_sampler.hpp"
#include "common/sampling/qmc.hpp"

namespace tally {
namespace {

using namespace sobol_burley;

TEST(SobolBurley, UnscrambledDimensionsAreSobols) {
  for (uint32_t i = 0; i < 70000; i += 7) {
    ASSERT_EQ(sobol0(i), sobol_bits(i, 0)) << i;
    ASSERT_EQ(sobol1(i), sobol_bits(i, 1)) << i;
  }
}

TEST(SobolBurley, OwenScrambleIsANestedBijection) {
  // On 16-bit prefixes (the low 16 bits zero in, ignored out): a permutation of the
  // 2^16 cells, and two inputs sharing their top b bits give outputs sharing theirs.
  for (uint32_t seed : {0u, 1u, 0xdeadbeefu, 0x12345678u}) {
    std::vector<uint32_t> seen(1u << 16, 0);
    for (uint32_t x = 0; x < (1u << 16); ++x) {
      const uint32_t y = owen_scramble(x << 16, seed) >> 16;
      ++seen[y];
      const uint32_t x2 = x ^ 1u;  // differs in the last bit only
      const uint32_t y2 = owen_scramble(x2 << 16, seed) >> 16;
      ASSERT_EQ(y >> 1, y2 >> 1) << "seed " << seed << " x " << x;
    }
    EXPECT_TRUE(std::all_of(seen.begin(), seen.end(), [](uint32_t c) { return c == 1; }));
  }
}

// Every aligned block of 2^m points of the pair has one point in each elementary
// interval [a 2^-p, (a+1) 2^-p) x [b 2^-(m-p), (b+1) 2^-(m-p)), for all p = 0..m.
bool is_02_net(const std::vector<std::pair<double, double>>& pts, int m) {
  for (int p = 0; p <= m; ++p) {
    std::vector<int> cells(size_t{1} << m, 0);
    for (const auto& [x, y] : pts) {
      const auto a = static_cast<size_t>(std::ldexp(x, p));
      const auto b = static_cast<size_t>(std::ldexp(y, m - p));
      if (++cells[(a << (m - p)) | b] > 1) return false;
    }
  }
  return true;
}

TEST(SobolBurley, AlignedBlocksOfEveryPairAreNets) {
  int checked = 0;
  for (uint64_t s = 0; s < 20; ++s) {
    const uint64_t key = SobolSample::replicate_key(stream_key(11, s), static_cast<uint32_t>(s % 4));
    for (uint32_t dim_pair = 0; dim_pair < 6; ++dim_pair) {
      for (int m = 0; m <= 10; ++m) {
        for (uint64_t block : {uint64_t{0}, uint64_t{1}, uint64_t{5}}) {
          std::vector<std::pair<double, double>> pts;
          for (uint64_t j = block << m; j < (block + 1) << m; ++j) {
            const SobolSample smp(key, j);
            pts.emplace_back(smp.uniform(2 * dim_pair), smp.uniform(2 * dim_pair + 1));
          }
          ASSERT_TRUE(is_02_net(pts, m)) << "seed " << s << " pair " << dim_pair << " m " << m << " block " << block;
          ++checked;
        }
      }
    }
  }
  EXPECT_EQ(checked, 20 * 6 * 11 * 3);
}

TEST(SobolBurley, FirstPointsAreNotTheSameAcrossPairsOrReplicates) {
  // Padding: each pair and each replicate has its own shuffle and scramble.
  const uint64_t k0 = SobolSample::replicate_key(stream_key(3, 9), 0);
  const uint64_t k1 = SobolSample::replicate_key(stream_key(3, 9), 1);
  const SobolSample a(k0, 0), b(k1, 0);
  EXPECT_NE(a.uniform(0), a.uniform(2));
  EXPECT_NE(a.uniform(0), b.uniform(0));
  EXPECT_NE(a.uniform(1), a.uniform(3));
}

TEST(SobolBurley, CoordinateIsUniformOverSeeds) {
  // Chi-square of point j (several j, both coordinates) over 2^16 seeds in 64 bins;
  // 12 tests at alpha = 1e-6 each: false-failure rate < 1.2e-5 (with the range bounds
  // below, < 1.5e-5).
  const boost::math::chi_squared dist(63);
  const double crit = boost::math::quantile(boost::math::complement(dist, 1e-6));
  constexpr int kSeeds = 1 << 16, kBins = 64;
  for (uint64_t j : {uint64_t{0}, uint64_t{1}, uint64_t{3}, uint64_t{17}, uint64_t{255}, uint64_t{1} << 33}) {
    for (uint32_t dim = 0; dim < 2; ++dim) {
      std::vector<double> counts(kBins, 0);
      double lo = 1, hi = 0;
      for (int s = 0; s < kSeeds; ++s) {
        const double u = SobolSample(stream_key(77, static_cast<uint64_t>(s)), j).uniform(dim + 4);
        ASSERT_GE(u, 0.0);
        ASSERT_LT(u, 1.0);
        lo = std::min(lo, u);
        hi = std::max(hi, u);
        counts[static_cast<size_t>(u * kBins)] += 1;
      }
      const double expect = static_cast<double>(kSeeds) / kBins;
      double chi2 = 0;
      for (double c : counts) chi2 += (c - expect) * (c - expect) / expect;
      EXPECT_LT(chi2, crit) << "j " << j << " dim " << dim;
      // The extremes reach both ends: P(min > 2^-12) = (1 - 2^-12)^65536 = e^-16 = 1.1e-7
      // per bound, 24 bounds: < 3e-6 (a coordinate squeezed into [2^-12, 1 - 2^-12], which
      // 64 bins cannot see, fails here).
      EXPECT_LT(lo, 0x1.0p-12) << "j " << j << " dim " << dim;
      EXPECT_GT(hi, 1.0 - 0x1.0p-12) << "j " << j << " dim " << dim;
    }
  }
}

TEST(SobolBurley, StratifiesBetterThanIndependentOnASmoothIntegrand) {
  // Mean of x y over 256 points: RQMC's spread over 64 seeds is far below MC's
  // (MC sd = sqrt(7/144 / 256) = 0.0138; a (0,2)-net at n = 256 is < 1e-3).
  double ss = 0;
  for (uint64_t s = 0; s < 64; ++s) {
    double sum = 0;
    for (uint64_t j = 0; j < 256; ++j) {
      const SobolSample smp(stream_key(5, s), j);
      sum += smp.uniform(0) * smp.uniform(1);
    }
    const double err = sum / 256 - 0.25;
    ss += err * err;
  }
  EXPECT_LT(std::sqrt(ss / 64), 1e-3);
}

}  // namespace
}  // namespace tally
