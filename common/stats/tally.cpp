#include "common/stats/tally.hpp"

namespace tally {

Tally Tally::from_batch(const double* x, size_t count) noexcept {
  Tally t;
  if (count == 0) return t;
  // Four independent accumulators: a fixed summation order (deterministic) that
  // still lets the CPU overlap the additions.
  double s[4] = {0, 0, 0, 0};
  size_t i = 0;
  for (; i + 4 <= count; i += 4) {
    s[0] += x[i];
    s[1] += x[i + 1];
    s[2] += x[i + 2];
    s[3] += x[i + 3];
  }
  for (; i < count; ++i) s[0] += x[i];
  const double n = static_cast<double>(count);
  const double mean = ((s[0] + s[1]) + (s[2] + s[3])) / n;
  double q[4] = {0, 0, 0, 0};
  double c[4] = {0, 0, 0, 0};
  i = 0;
  for (; i + 4 <= count; i += 4) {
    for (int k = 0; k < 4; ++k) {
      const double d = x[i + static_cast<size_t>(k)] - mean;
      q[k] += d * d;
      c[k] += d;
    }
  }
  for (; i < count; ++i) {
    const double d = x[i] - mean;
    q[0] += d * d;
    c[0] += d;
  }
  const double sum_d = (c[0] + c[1]) + (c[2] + c[3]);
  // Compensation term of the corrected two-pass algorithm (Chan, Golub, LeVeque 1983):
  // removes the rounding error left in the first-pass mean.
  t.n = count;
  t.mean = mean + sum_d / n;
  t.m2 = ((q[0] + q[1]) + (q[2] + q[3])) - sum_d * sum_d / n;
  if (t.m2 < 0.0) t.m2 = 0.0;
  return t;
}

}  // namespace tally
