#pragma once
// Error bars of randomized quasi-Monte Carlo: K independent randomizations
// ("replicates") of one low-discrepancy point set, each tallied in its own channel.
//
// Inside a replicate the samples are not independent (they are stratified), so a
// replicate's own sample variance says nothing about the error of its mean (it
// overstates it by a scene-dependent factor). Across replicates the means are
// independent and identically distributed unbiased estimates, so
//   estimate = (1/K) sum_r mean_r,   se^2 = sum_r (mean_r - estimate)^2 / (K (K - 1)),
// and (estimate - I) / se is Student t with K - 1 degrees of freedom when the replicate
// means are close to normal (each is an average of many points). With K = 1 this is the
// ordinary independent-sample estimate: mean and std_error of the one tally.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <vector>

#include "common/stats/confidence.hpp"
#include "common/stats/tally.hpp"

namespace tally {

struct ReplicatedEstimate {
  double mean = 0.0;
  double std_error = std::numeric_limits<double>::quiet_NaN();  // of `mean`; NaN if unknown
  uint64_t n = 0;             // samples in all replicates
  uint64_t critical_n = 0;    // pass to critical_value(): K for K > 1 (K - 1 dof), else n
  bool has_error() const noexcept { return std::isfinite(std::fabs(std_error)); }
  // Per-sample variance that gives this std_error at n samples: n se^2 (equal to the
  // sample variance for independent samples). Efficiencies 1/(sigma^2 t) use it, so
  // estimators and samplers compare fairly.
  double effective_variance() const noexcept {
    return has_error() ? static_cast<double>(n) * std_error * std_error : 0.0;
  }
  double half_width(double confidence) const { return critical_value(confidence, critical_n) * std_error; }
};

// The estimate of K > 1 replicates whose means are all known: their average, and the
// standard error from their spread (K - 1 dof). `mean_of(r)` is replicate r's mean; `n`
// the samples in all. The one rule for tallies (combine_replicates) and for sum channels
// (ImageKernel).
template <class MeanOf>
ReplicatedEstimate replicate_spread(uint32_t replicates, uint64_t n, MeanOf mean_of) {
  ReplicatedEstimate e;
  e.n = n;
  e.critical_n = replicates;
  double sum = 0.0;
  for (uint32_t r = 0; r < replicates; ++r) sum += mean_of(r);
  e.mean = sum / replicates;
  double ss = 0.0;
  for (uint32_t r = 0; r < replicates; ++r) {
    const double d = mean_of(r) - e.mean;
    ss += d * d;
  }
  e.std_error = std::sqrt(ss / (static_cast<double>(replicates) * (replicates - 1)));
  return e;
}

// Replicate r of the channel is tallies[r * stride].
inline ReplicatedEstimate combine_replicates(const Tally* tallies, size_t stride, uint32_t replicates) noexcept {
  ReplicatedEstimate e;
  if (replicates <= 1) {
    const Tally& t = tallies[0];
    e.mean = t.mean;
    e.n = t.n;
    e.critical_n = t.n;
    if (t.n > 1) e.std_error = t.std_error();
    return e;
  }
  bool all = true;
  for (uint32_t r = 0; r < replicates; ++r) {
    e.n += tallies[r * stride].n;
    all = all && tallies[r * stride].n > 0;
  }
  e.critical_n = replicates;
  if (!all) {  // early on: the pooled mean of what there is, no error bar yet
    Tally pooled;
    for (uint32_t r = 0; r < replicates; ++r) pooled.merge(tallies[r * stride]);
    e.mean = pooled.mean;
    return e;
  }
  return replicate_spread(replicates, e.n, [&](uint32_t r) { return tallies[r * stride].mean; });
}

// One block's samples of one RGB pixel or point, kept by replicate until they are
// tallied: replicate r's component c goes to channel 3 r + c (the layout that
// combine_replicates reads with stride 3).
class ReplicateRgbSamples {
 public:
  ReplicateRgbSamples(uint32_t replicates, uint64_t samples) : v_(3 * static_cast<size_t>(replicates)) {
    for (auto& a : v_) a.reserve(samples / replicates + 1);
  }
  void clear() noexcept {
    for (auto& a : v_) a.clear();
  }
  void add(uint32_t replicate, double r, double g, double b) {
    v_[3 * static_cast<size_t>(replicate)].push_back(r);
    v_[3 * static_cast<size_t>(replicate) + 1].push_back(g);
    v_[3 * static_cast<size_t>(replicate) + 2].push_back(b);
  }
  // Channel c's tally of its samples in order (Tally::from_batch), into out[c] for c < 3 K.
  void tally_into(Tally* out) const noexcept {
    for (size_t c = 0; c < v_.size(); ++c) out[c] = Tally::from_batch(v_[c].data(), v_[c].size());
  }

 private:
  std::vector<std::vector<double>> v_;  // [replicate * 3 + rgb]
};

}  // namespace tally
