#include "common/sampling/stratified.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

namespace tally {

std::uint64_t stratum_count(std::uint32_t strata_per_dim, std::uint32_t dims) {
  if (strata_per_dim == 0 || dims == 0) {
    throw std::invalid_argument("stratified: strata_per_dim and dims must be positive");
  }
  std::uint64_t n = 1;
  for (std::uint32_t i = 0; i < dims; ++i) {
    if (n > std::numeric_limits<std::uint64_t>::max() / strata_per_dim) {
      throw std::invalid_argument("stratified: " + std::to_string(strata_per_dim) + "^" +
                                  std::to_string(dims) + " strata overflow 64 bits");
    }
    n *= strata_per_dim;
  }
  return n;
}

void stratified_point(std::uint32_t strata_per_dim, std::uint64_t stratum,
                      std::span<const double> jitter, std::span<double> out) {
  const double k = static_cast<double>(strata_per_dim);
  for (std::size_t i = 0; i < out.size(); ++i) {
    const auto cell = static_cast<double>(stratum % strata_per_dim);
    stratum /= strata_per_dim;
    const double upper = (cell + 1.0) / k;
    out[i] = std::min((cell + jitter[i]) / k, std::nextafter(upper, 0.0));
  }
}

void stratified_sample(std::uint32_t strata_per_dim, std::uint64_t sample_index, SampleRng& rng,
                       std::span<double> out) {
  const std::uint64_t cells = stratum_count(strata_per_dim, static_cast<std::uint32_t>(out.size()));
  std::array<double, 64> jitter{};
  if (out.size() > jitter.size()) throw std::invalid_argument("stratified: more than 64 dims");
  for (std::size_t i = 0; i < out.size(); ++i) jitter[i] = rng.next();
  stratified_point(strata_per_dim, sample_index % cells, std::span(jitter).first(out.size()), out);
}

}  // namespace tally
