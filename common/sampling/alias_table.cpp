#include "common/sampling/alias_table.hpp"

#include <algorithm>
#include <limits>
#include <stdexcept>

#include "common/sampling/discrete_cdf.hpp"
#include "common/sampling/safe_math.hpp"

namespace tally {

AliasTable::AliasTable(std::span<const double> weights) {
  validate_weights(weights, "AliasTable");
  const std::size_t n = weights.size();
  if (n > std::numeric_limits<std::uint32_t>::max()) {
    throw std::invalid_argument("AliasTable: more than 2^32 - 1 weights");
  }
  const double scale = 1.0 / *std::max_element(weights.begin(), weights.end());
  double total = 0;
  for (const double w : weights) total += w * scale;
  pmf_.resize(n);
  for (std::size_t i = 0; i < n; ++i) pmf_[i] = weights[i] * scale / total;

  // Vose: scaled probabilities p_i * n; "small" (< 1) columns are topped up by "large" ones.
  std::vector<double> scaled(n);
  std::vector<std::uint32_t> small, large;
  for (std::size_t i = 0; i < n; ++i) {
    scaled[i] = pmf_[i] * static_cast<double>(n);
    (scaled[i] < 1.0 ? small : large).push_back(static_cast<std::uint32_t>(i));
  }
  bins_.assign(n, Bin{1.0, 0});
  while (!small.empty() && !large.empty()) {
    const std::uint32_t s = small.back();
    small.pop_back();
    const std::uint32_t l = large.back();
    bins_[s] = Bin{scaled[s], l};
    scaled[l] -= 1.0 - scaled[s];
    if (scaled[l] < 1.0) {
      large.pop_back();
      small.push_back(l);
    }
  }
  // Leftovers have scaled probability 1 up to rounding: they keep their own column. A
  // zero-weight leftover (only possible through rounding) must still never be returned,
  // so its column points at the heaviest entry instead.
  const auto heaviest =
      static_cast<std::uint32_t>(std::max_element(pmf_.begin(), pmf_.end()) - pmf_.begin());
  for (const std::uint32_t i : large) bins_[i] = Bin{1.0, i};
  for (const std::uint32_t i : small) bins_[i] = pmf_[i] > 0 ? Bin{1.0, i} : Bin{0.0, heaviest};
}

std::size_t AliasTable::sample(double u) const {
  // One uniform does both jobs: its integer part picks the column, the fraction is the coin.
  const double scaled = clamp_unit(u) * static_cast<double>(bins_.size());
  const std::size_t column = std::min(static_cast<std::size_t>(scaled), bins_.size() - 1);
  const double coin = scaled - static_cast<double>(column);
  const Bin& bin = bins_[column];
  // A zero-weight column has keep == 0 and coin >= 0, so it always takes its alias.
  return coin < bin.keep ? column : bin.alias;
}

}  // namespace tally
