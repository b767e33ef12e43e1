#pragma once
// One channel's running statistics: count, mean and M2 (sum of squared deviations),
// updated with Welford's recurrence and merged with Chan et al.'s formula. Never
// E[x^2] - E[x]^2 on raw sums: that cancels catastrophically (see docs/numerics.md).
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>

namespace tally {

struct Tally {
  uint64_t n = 0;
  double mean = 0.0;
  double m2 = 0.0;

  void add(double x) noexcept {
    ++n;
    const double delta = x - mean;
    mean += delta / static_cast<double>(n);
    m2 += delta * (x - mean);
  }

  // Chan, Golub & LeVeque's pairwise merge. Order matters in the last bit: callers
  // that need bit-identical results merge in a fixed order.
  void merge(const Tally& o) noexcept {
    if (o.n == 0) return;
    if (n == 0) {
      *this = o;
      return;
    }
    const double na = static_cast<double>(n);
    const double nb = static_cast<double>(o.n);
    const double total = na + nb;
    const double delta = o.mean - mean;
    mean += delta * (nb / total);
    m2 += o.m2 + delta * delta * (na * nb / total);
    n += o.n;
  }

  // Exact statistics of a batch by the compensated two-pass algorithm; much cheaper
  // per sample than Welford (no division) and at least as accurate.
  static Tally from_batch(const double* x, size_t count) noexcept;

  double variance() const noexcept {  // sample variance of one sample
    return n > 1 ? m2 / static_cast<double>(n - 1) : std::numeric_limits<double>::quiet_NaN();
  }
  double std_error() const noexcept {  // standard error of the mean
    return n > 1 ? std::sqrt(variance() / static_cast<double>(n))
                 : std::numeric_limits<double>::quiet_NaN();
  }
  double relative_error() const noexcept {
    return mean != 0.0 ? std_error() / std::fabs(mean) : std::numeric_limits<double>::infinity();
  }

  friend bool operator==(const Tally&, const Tally&) = default;
};

}  // namespace tally
