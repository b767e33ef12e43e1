#include "common/sampling/discrete_cdf.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "common/sampling/safe_math.hpp"

namespace tally {

void validate_weights(std::span<const double> weights, const char* what) {
  if (weights.empty()) throw std::invalid_argument(std::string(what) + ": no weights given");
  bool any_positive = false;
  for (std::size_t i = 0; i < weights.size(); ++i) {
    const double w = weights[i];
    if (!std::isfinite(w) || w < 0) {
      throw std::invalid_argument(std::string(what) + ": weight[" + std::to_string(i) + "] = " +
                                  std::to_string(w) + " is not a finite non-negative number");
    }
    any_positive = any_positive || w > 0;
  }
  if (!any_positive) {
    throw std::invalid_argument(std::string(what) +
                                ": all weights are zero (a distribution needs positive mass)");
  }
}

DiscreteCdf::DiscreteCdf(std::span<const double> weights) {
  validate_weights(weights, "DiscreteCdf");
  const std::size_t n = weights.size();
  // Scale by the largest weight first so that huge finite weights cannot overflow the sum.
  const double scale = 1.0 / *std::max_element(weights.begin(), weights.end());
  double total = 0;
  std::size_t last_positive = 0;
  cdf_.assign(n + 1, 0.0);
  for (std::size_t i = 0; i < n; ++i) {
    total += weights[i] * scale;
    cdf_[i + 1] = total;
    if (weights[i] > 0) last_positive = i;
  }
  pmf_.resize(n);
  for (std::size_t i = 0; i < n; ++i) {
    pmf_[i] = weights[i] * scale / total;
    // A zero weight must leave an empty bucket even after the division rounds.
    cdf_[i + 1] = weights[i] > 0 ? cdf_[i + 1] / total : cdf_[i];
  }
  // The last positive bucket ends at exactly 1 so that every u < 1 finds a positive
  // bucket; trailing zero-weight buckets stay empty.
  for (std::size_t i = last_positive + 1; i <= n; ++i) cdf_[i] = 1.0;
}

std::size_t DiscreteCdf::sample(double u) const {
  u = clamp_unit(u);
  // First entry > u, minus one: cdf_[i] <= u < cdf_[i + 1], so bucket i is non-empty.
  const auto it = std::upper_bound(cdf_.begin() + 1, cdf_.end(), u);
  return static_cast<std::size_t>(it - cdf_.begin()) - 1;
}

std::size_t DiscreteCdf::sample_remapped(double u, double* u_remapped) const {
  const std::size_t i = sample(u);
  *u_remapped = clamp_unit((clamp_unit(u) - cdf_[i]) / (cdf_[i + 1] - cdf_[i]));
  return i;
}

}  // namespace tally
