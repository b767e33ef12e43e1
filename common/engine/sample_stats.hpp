#pragma once
// What blocks report besides tallies and that the job state accumulates: importance
// weights (for the effective sample size) and the first unusable sample. Shared by
// kernel.hpp (BlockResult) and job_state.hpp, so neither includes the other.
#include <cstdint>
#include <string>
#include <vector>

namespace tally {

// Importance weights seen by a block, for the effective sample size
// ESS = (sum w)^2 / sum w^2 (Kish).
struct WeightStats {
  double sum_w = 0.0;
  double sum_w2 = 0.0;
  void add(double w) noexcept {
    sum_w += w;
    sum_w2 += w * w;
  }
  void merge(const WeightStats& o) noexcept {
    sum_w += o.sum_w;
    sum_w2 += o.sum_w2;
  }
  bool empty() const noexcept { return sum_w2 == 0.0; }
  double ess() const noexcept { return sum_w2 > 0 ? sum_w * sum_w / sum_w2 : 0.0; }
  friend bool operator==(const WeightStats&, const WeightStats&) = default;
};

// The first sample whose value could not be used (NaN/Inf), with where it happened.
struct SampleFault {
  uint64_t sample_index = 0;
  uint32_t channel = 0;
  double value = 0.0;
  std::vector<double> point;  // the integration point or pixel coordinates
  std::string message;
};

}  // namespace tally
