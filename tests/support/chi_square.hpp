#pragma once
// Pearson's chi-square goodness-of-fit p-value, shared by the sampling tests (light
// directions, GGX, the environment map). Cells whose expected count is below 5 are
// pooled into one cell; dof = (cells after pooling) - 1.
#include <boost/math/distributions/chi_squared.hpp>

#include <cmath>
#include <vector>

namespace tally::test {

inline double chi_square_p(const std::vector<double>& observed, const std::vector<double>& expected) {
  double chi2 = 0, pool_o = 0, pool_e = 0;
  int dof = -1;
  for (size_t i = 0; i < observed.size(); ++i) {
    if (expected[i] < 5) {
      pool_o += observed[i];
      pool_e += expected[i];
      continue;
    }
    chi2 += (observed[i] - expected[i]) * (observed[i] - expected[i]) / expected[i];
    ++dof;
  }
  if (pool_e > 0) {
    chi2 += (pool_o - pool_e) * (pool_o - pool_e) / pool_e;
    ++dof;
  }
  return boost::math::cdf(boost::math::complement(boost::math::chi_squared(dof), chi2));
}

// The per-test level that keeps the family-wise false-failure rate at `alpha` over
// `tests` independent tests (Šidák): 1 - (1 - alpha)^(1 / tests).
inline double sidak_level(double alpha, int tests) { return 1.0 - std::pow(1.0 - alpha, 1.0 / tests); }

}  // namespace tally::test
