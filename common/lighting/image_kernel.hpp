#pragma once
// Image queries: every pixel's radiance through a pinhole camera. Partitions are
// square tiles; the channels are tile-major (tile t owns [tile_first_channel(t),
// + 3 * tile pixels), its pixels row-major inside the tile, RGB interleaved), so a block
// (one tile x a range of samples per pixel) fills one contiguous channel range.
// "Samples" of the job are samples per pixel: pass k draws min(2^k, max_pass_spp) spp.
// Pixel (x, y), sample i uses the job's sampler (common/lighting/pixel_sampler.hpp) on
// stream_key(seed, y * width + x): dimensions 0-1 jitter the pixel, the path uses 2
// onwards. With K replicates (the sobol sampler) each pixel has K x 3 channels,
// replicate-major (replicate r of channel c at pixel_channel + 3 r + c); sample i goes to
// replicate i mod K. A pixel's value and standard error combine its replicates
// (common/stats/replicates.hpp): every reader goes through pixel_estimate().
// State: with K > 1 the channels are sum channels (Kernel::sum_count, 4 bytes each): a
// tile's blocks cover samples [0, n) of each of its pixels (n = partition_samples[t]),
// so replicate r of every pixel there has the same count (replicate_count), and its mean
// is its sum over that count; only the spread of the K means makes the error bar, so
// nothing else is kept. A non-finite sample value counts as 0 (and in the nonfinite
// counter). With K = 1 (independent samples) the error bar is the samples' own variance:
// the channels are tallies (24 bytes), and a non-finite value is left out.
//
// Error summary (what stop rules on images look at): per pixel, the half-width h of the
// confidence interval of each channel, and r = h / (|mean| + delta) with
// delta = 1e-3 * (mean over the image) guarding black pixels. abs_error is the mean of h
// over all channels, rel_error the mean of r. (A percentile would punish a few fireflies
// more; the mean tracks overall noise, which is what progressive previews show.)
// Adaptive sampling: a tile stays active while it has fewer than min_spp samples or any
// of its pixels has r above the adaptive target, r computed on the pixel's RGB average
// (sum of the channel half-widths / sum of |channel means|).
#include <memory>
#include <optional>
#include <vector>

#include "common/lighting/lighting_counters.hpp"
#include "common/engine/image_source.hpp"
#include "common/engine/job_state.hpp"
#include "common/engine/kernel.hpp"
#include "common/lighting/compiled_scene.hpp"
#include "common/lighting/pixel_sampler.hpp"
#include "common/stats/replicates.hpp"

namespace tally {

struct AdaptiveSettings {
  double rel_error = 0.05;
  uint64_t min_spp = 16;
};

class ImageKernel final : public Kernel, public ImageSource {
 public:
  ImageKernel(std::shared_ptr<const CompiledScene> scene, PathSettings settings, uint64_t seed,
              int tile_size, uint64_t max_pass_spp, std::optional<AdaptiveSettings> adaptive,
              SamplerSettings sampler = {SamplerKind::independent, 1});

  // Kernel
  size_t channel_count() const override { return k_ > 1 ? 0 : pixel_channels(); }
  size_t sum_count() const override { return k_ > 1 ? pixel_channels() : 0; }
  // A K > 1 image of results version 2 or earlier (a tally per replicate channel): each
  // sum becomes mean x count (a non-finite sample, left out then, counts as 0 now).
  bool upgrade_state(JobState& state) const override;
  uint32_t partition_count() const override { return tile_count(); }
  PassSchedule schedule() const override;
  std::vector<uint32_t> active_partitions(const JobState& state) const override;
  // Adaptive sampling picks tiles from merged results; without it every tile gets samples.
  bool plans_from_counts() const override { return !adaptive_; }
  void run_block(const Block& block, BlockResult& out) const override;
  std::span<const std::string_view> counter_names() const override { return lighting_counter_names(); }
  std::vector<std::string> warnings(const JobState& state) const override { return lighting_counter_warnings(state); }
  ErrorSummary error_summary(const JobState& state, double confidence) const override;
  // The image's mean radiance over all pixels and channels, with its standard error.
  std::optional<Headline> headline(const JobState& state) const override;
  uint64_t resident_bytes() const override { return scene_->scene.resident_bytes(); }

  // ImageSource
  int width() const override { return width_; }
  int height() const override { return height_; }
  uint32_t tile_count() const override { return static_cast<uint32_t>(tiles_x_ * tiles_y_); }
  TileRect tile_rect(uint32_t tile) const override;
  ImageSnapshot snapshot(const JobState& state, const TileRect& rect) const override;
  using ImageSource::snapshot;

  size_t pixel_channel(int x, int y) const;  // first of the pixel's 3 K channels (or sums)
  // 3 K per pixel: the tallies (K = 1) or sums (K > 1) of the whole image.
  size_t pixel_channels() const {
    return 3 * static_cast<size_t>(k_) * static_cast<size_t>(width_) * static_cast<size_t>(height_);
  }
  int tile_size() const { return tile_; }
  uint32_t replicates() const { return k_; }
  const SamplerSettings& sampler() const { return sampler_; }
  // Channel c (0-2) of the pixel whose first channel is `ch`: value and standard error.
  ReplicatedEstimate pixel_estimate(const JobState& state, size_t ch, size_t c) const;

 private:
  // Samples replicate r of each pixel has when its tile has n: sample i goes to replicate
  // i mod K, and a tile's blocks cover samples [0, n) of each of its pixels.
  double replicate_count(uint64_t n, uint32_t r) const {
    return static_cast<double>(n / k_ + (r < n % k_ ? 1 : 0));
  }
  // pixel_estimate of a pixel of tile `tile`.
  ReplicatedEstimate estimate_in(const JobState& state, uint32_t tile, size_t ch, size_t c) const;
  double pixel_rel_error(const JobState& state, uint32_t tile, size_t ch, double z_conf, double delta) const;
  template <class Sample>
  void run_pixels(const Block& block, BlockResult& out) const;
  double image_mean(const JobState& state) const;

  std::shared_ptr<const CompiledScene> scene_;
  PathSettings settings_;
  uint64_t seed_;
  int width_, height_, tile_, tiles_x_, tiles_y_;
  uint64_t max_pass_spp_;
  std::optional<AdaptiveSettings> adaptive_;
  SamplerSettings sampler_;
  uint32_t k_;
  std::vector<size_t> tile_first_;
  Vec3 cam_pos_, cam_fwd_, cam_right_, cam_up_;
  double tan_half_ = 0, aspect_ = 1;
};

}  // namespace tally
