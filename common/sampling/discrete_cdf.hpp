#pragma once
// Sampling a discrete distribution by CDF inversion: pick index i when the uniform u
// falls in its CDF bucket [cdf(i), cdf(i+1)). O(log n) per sample (binary search);
// the alias table is O(1) but cannot be inverted or remap the uniform.
#include <cstddef>
#include <span>
#include <vector>

namespace tally {

class DiscreteCdf {
 public:
  // weights: finite, >= 0, at least one > 0 (else std::invalid_argument). They need not
  // sum to 1. Zero-weight entries get an empty bucket and are never sampled.
  explicit DiscreteCdf(std::span<const double> weights);

  std::size_t size() const { return pmf_.size(); }

  // u in [0, 1) -> index with probability pdf(index).
  std::size_t sample(double u) const;
  // Same index, plus u rescaled to [0, 1) within the chosen bucket: the leftover
  // randomness of u is reused (e.g. to place the point inside a chosen cell).
  std::size_t sample_remapped(double u, double* u_remapped) const;

  // Probability of index i (0 for i >= size()).
  double pdf(std::size_t i) const { return i < pmf_.size() ? pmf_[i] : 0.0; }
  // cdf(i) = P(index < i) for i in [0, size()]; cdf(size()) == 1 exactly.
  double cdf(std::size_t i) const { return cdf_[i]; }

 private:
  std::vector<double> pmf_;
  std::vector<double> cdf_;  // size() + 1 entries, cdf_[0] = 0
};

// Shared validation for discrete distributions: throws std::invalid_argument naming the
// first bad weight (negative, NaN or infinite) or an empty / all-zero vector. `what`
// names the caller in the message.
void validate_weights(std::span<const double> weights, const char* what);

}  // namespace tally
