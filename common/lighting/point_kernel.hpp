#pragma once
// Point queries: L_o at given points for several estimators on common random numbers
// (estimator e at point k, sample i uses SampleRng(stream_key(seed, k), i) for every e).
// With the sobol sampler, estimator e at point k, sample i uses replicate r = i mod K,
// point i div K of SobolSample(replicate_key(stream_key(seed, k), r)) -- again the same
// for every e. Channel layout: (((e * points) + k) * K + r) * 3 + rgb (K = 1 for the
// independent sampler); estimate() combines the replicates. One partition. Wall time per estimator
// is measured inside run_block (process-local, not checkpointed: it is a rate, not a
// result) to report time per sample and efficiency 1 / (sigma^2 t).
#include <atomic>
#include <memory>
#include <vector>

#include "common/lighting/lighting_counters.hpp"
#include "common/engine/job_state.hpp"
#include "common/engine/kernel.hpp"
#include "common/lighting/compiled_scene.hpp"
#include "common/lighting/pixel_sampler.hpp"
#include "common/stats/replicates.hpp"

namespace tally {

struct QueryPoint {
  Vertex vertex;  // local coordinates, normal on the side of wo
  Rgb emission{};  // the point's own L_e towards wo
  Vec3 world_p{};
};

class PointKernel final : public Kernel {
 public:
  PointKernel(std::shared_ptr<const CompiledScene> scene, std::vector<QueryPoint> points,
              std::vector<Strategy> strategies, int max_depth, bool russian_roulette, uint64_t seed,
              SamplerSettings sampler = {SamplerKind::independent, 1});

  size_t channel_count() const override { return strategies_.size() * points_.size() * 3 * k_; }
  PassSchedule schedule() const override;
  bool plans_from_counts() const override { return true; }
  void run_block(const Block& block, BlockResult& out) const override;
  std::span<const std::string_view> counter_names() const override { return lighting_counter_names(); }
  std::vector<std::string> warnings(const JobState& state) const override { return lighting_counter_warnings(state); }
  // The worst (estimator, point, rgb) estimate, its error from the replicates.
  ErrorSummary error_summary(const JobState& state, double confidence) const override;
  // Progress shows estimator 0 at point 0 (red), replicates combined.
  std::optional<Headline> headline(const JobState& state) const override;
  uint64_t resident_bytes() const override { return scene_->scene.resident_bytes(); }

  size_t channel(size_t estimator, size_t point, int rgb, uint32_t replicate = 0) const {
    return ((estimator * points_.size() + point) * k_ + replicate) * 3 + static_cast<size_t>(rgb);
  }
  // Value and standard error of one (estimator, point, rgb), all replicates combined.
  ReplicatedEstimate estimate(const JobState& state, size_t estimator, size_t point, int rgb) const {
    return combine_replicates(&state.channels[channel(estimator, point, rgb)], 3, k_);
  }
  uint32_t replicates() const { return k_; }
  const SamplerSettings& sampler() const { return sampler_; }
  const std::vector<QueryPoint>& points() const { return points_; }
  const std::vector<Strategy>& strategies() const { return strategies_; }
  // Seconds spent per sample of one estimator at one point (0 before any sample).
  double seconds_per_sample(size_t estimator) const;

 private:
  std::shared_ptr<const CompiledScene> scene_;
  std::vector<QueryPoint> points_;
  std::vector<Strategy> strategies_;
  int max_depth_;
  bool rr_;
  uint64_t seed_;
  SamplerSettings sampler_;
  uint32_t k_;
  template <class Sample>
  void run_samples(const Block& block, BlockResult& out) const;
  std::unique_ptr<std::atomic<uint64_t>[]> nanos_;    // per estimator
  std::unique_ptr<std::atomic<uint64_t>[]> samples_;  // per estimator (point-samples)
};

}  // namespace tally
