#pragma once
// Walker's alias method with Vose's O(n) construction: O(1) sampling of a discrete
// distribution (one column pick + one biased coin from a single uniform). Preferred over
// DiscreteCdf when n is large and sampling is hot; it cannot be inverted.
#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

namespace tally {

class AliasTable {
 public:
  // Same validation as DiscreteCdf: finite, >= 0, not all zero (std::invalid_argument).
  explicit AliasTable(std::span<const double> weights);

  std::size_t size() const { return pmf_.size(); }
  // u in [0, 1) -> index with probability pdf(index). Zero-weight entries never come out.
  std::size_t sample(double u) const;
  double pdf(std::size_t i) const { return i < pmf_.size() ? pmf_[i] : 0.0; }

 private:
  struct Bin {
    double keep;          // probability of keeping this column's own index
    std::uint32_t alias;  // index returned otherwise
  };
  std::vector<double> pmf_;
  std::vector<Bin> bins_;
};

}  // namespace tally
