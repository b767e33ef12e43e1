#pragma once
// Confidence intervals for a mean: Student t for small samples, the normal limit
// for large ones (they agree to < 1e-4 relative beyond ~10^4 samples).
#include <cstdint>

#include "common/stats/tally.hpp"

namespace tally {

// Two-sided critical value for a confidence level in (0, 1) with n samples.
double critical_value(double confidence, uint64_t n);

struct Interval {
  double lo = 0.0;
  double hi = 0.0;
};

Interval confidence_interval(const Tally& t, double confidence);

// Samples a tally needs for its half-width (z * sigma / sqrt(n)) to reach `half_width`.
double samples_for_half_width(double sigma, double half_width, double confidence);

}  // namespace tally
