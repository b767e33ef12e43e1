#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "common/sampling/qmc.hpp"

namespace tally {
namespace {

std::vector<std::vector<double>> points(uint64_t seed, uint32_t dims, uint32_t first, size_t n) {
  ScrambledSobolSet set(seed, dims);
  std::vector<std::vector<double>> rows(dims, std::vector<double>(n));
  std::vector<double*> ptr(dims);
  for (uint32_t d = 0; d < dims; ++d) ptr[d] = rows[d].data();
  set.fill(first, n, ptr.data());
  return rows;
}

// The scramble keeps the net: in every dimension, the first 2^m points put exactly one
// point in each dyadic interval of length 2^-m, and pairs of dimensions stay
// (t, m, 2)-nets (here: every 2^-5 x 2^-5 cell of 1024 points holds exactly one point
// for dimensions 0 and 1, whose t = 0).
TEST(ScrambledSobolSet, KeepsTheNetStructure) {
  for (uint64_t seed : {1, 2, 3}) {
    const auto r = points(seed, 8, 0, 1024);
    for (uint32_t d = 0; d < 8; ++d) {
      std::vector<int> count(1024, 0);
      for (double x : r[d]) {
        ASSERT_GT(x, 0.0);
        ASSERT_LT(x, 1.0);
        ++count[static_cast<size_t>(x * 1024)];
      }
      EXPECT_EQ(*std::min_element(count.begin(), count.end()), 1) << "dim " << d;
    }
    std::vector<int> cells(1024, 0);
    for (size_t i = 0; i < 1024; ++i) {
      ++cells[static_cast<size_t>(r[0][i] * 32) * 32 + static_cast<size_t>(r[1][i] * 32)];
    }
    EXPECT_EQ(*std::max_element(cells.begin(), cells.end()), 1);
  }
}

// Filling from any starting point gives the same points as one long fill.
TEST(ScrambledSobolSet, RandomAccessMatchesSequentialFill) {
  const auto all = points(7, 5, 0, 600);
  for (uint32_t first : {1u, 255u, 256u, 377u}) {
    const auto part = points(7, 5, first, 600 - first);
    for (uint32_t d = 0; d < 5; ++d) {
      for (size_t i = 0; i + first < 600; ++i) ASSERT_EQ(part[d][i], all[d][i + first]);
    }
  }
}

// Each coordinate is uniform over scrambles: the mean of a point's coordinate over
// 20,000 seeds is 1/2 within 4 sigma (sigma = sqrt(1/12 / 20000) = 0.002), and so is
// the fraction below 1/4 (sigma = 0.0031).
TEST(ScrambledSobolSet, EachPointIsUniformOverScrambles) {
  for (uint32_t index : {0u, 1u, 13u, 1000u}) {
    double sum = 0.0;
    int below = 0;
    const int seeds = 20000;
    for (int s = 0; s < seeds; ++s) {
      const double x = points(static_cast<uint64_t>(s), 3, index, 1)[2][0];
      sum += x;
      below += x < 0.25 ? 1 : 0;
    }
    EXPECT_NEAR(sum / seeds, 0.5, 4 * 0.00204) << index;
    EXPECT_NEAR(static_cast<double>(below) / seeds, 0.25, 4 * 0.00306) << index;
  }
}

// Unbiased with a tiny variance on a smooth integrand: prod(x_i) over [0,1]^4 = 1/16.
TEST(ScrambledSobolSet, SmoothIntegrandHasTinyVariance) {
  const int reps = 200;
  const size_t n = 1024;
  double sum = 0.0, sum2 = 0.0;
  for (int s = 0; s < reps; ++s) {
    const auto r = points(1000 + static_cast<uint64_t>(s), 4, 0, n);
    double est = 0.0;
    for (size_t i = 0; i < n; ++i) est += r[0][i] * r[1][i] * r[2][i] * r[3][i];
    est /= static_cast<double>(n);
    sum += est;
    sum2 += est * est;
  }
  const double mean = sum / reps;
  const double var = (sum2 - sum * mean) / (reps - 1);
  EXPECT_NEAR(mean, 1.0 / 16.0, 4 * std::sqrt(var / reps));
  // Plain MC: Var = (1/81 - 1/256)/1024 = 8.3e-6; RQMC is orders of magnitude below.
  EXPECT_LT(var, 8.3e-6 / 1000);
}

}  // namespace
}  // namespace tally
