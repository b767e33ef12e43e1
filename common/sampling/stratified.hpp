#pragma once
// Jittered stratified sampling of [0,1)^s: k strata per dimension, k^s cells, one point
// per cell at a uniform jitter inside it. Each point alone is uniform on its cell; a
// sample index walks the cells (index mod k^s), so any whole number of sweeps is an
// unbiased estimator whose variance never exceeds plain MC's at equal N.
#include <cstdint>
#include <span>

#include "common/rng/counter_rng.hpp"

namespace tally {

// k^s, or std::invalid_argument when k == 0, s == 0 or k^s overflows 64 bits.
std::uint64_t stratum_count(std::uint32_t strata_per_dim, std::uint32_t dims);

// Point in cell `stratum` (digits of stratum in base k, dimension 0 least significant),
// offset by jitter[i] in [0, 1). out.size() == jitter.size() == s; stratum < k^s.
// The result stays inside its cell even when (cell + jitter) / k rounds up.
void stratified_point(std::uint32_t strata_per_dim, std::uint64_t stratum,
                      std::span<const double> jitter, std::span<double> out);

// Convenience for sample `sample_index` of a stratified sweep: stratum = index mod k^s,
// jitter from rng.next() (out.size() uniforms).
void stratified_sample(std::uint32_t strata_per_dim, std::uint64_t sample_index, SampleRng& rng,
                       std::span<double> out);

// Density of a stratified point over the unit cube (over a whole sweep): 1.
constexpr double stratified_pdf() {
  return 1.0;
}

}  // namespace tally
