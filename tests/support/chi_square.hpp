#pragma once
// Pearson's chi-square test of binned sample counts against expected counts (the
// lighting and GGX sampling tests): cells whose expected count is below 5 are pooled
// into one cell. Returns the p-value; callers compare it with their Šidák-corrected
// alpha. (tests/sampling/chi_square_support.hpp is the fuller harness of the sampling
// routines, with Mitsuba's pooling order and its own suite-wide correction.)
#include <boost/math/distributions/chi_squared.hpp>
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

}  // namespace tally::test
