#include "common/lighting/image_kernel.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <type_traits>

#include "common/engine/block_abandon.hpp"
#include "common/lighting/embree_device.hpp"
#include "common/stats/confidence.hpp"

namespace tally {

namespace {
// critical_value (a t quantile) is costly; almost every channel has the same n.
struct CriticalCache {
  double confidence = -1;
  uint64_t n = 0;
  double z = 0;
  double operator()(double conf, uint64_t count) {
    if (conf != confidence || count != n) {
      confidence = conf;
      n = count;
      z = critical_value(conf, count);
    }
    return z;
  }
};
}  // namespace

ImageKernel::ImageKernel(std::shared_ptr<const CompiledScene> scene, PathSettings settings, uint64_t seed,
                         int tile_size, uint64_t max_pass_spp, std::optional<AdaptiveSettings> adaptive,
                         SamplerSettings sampler)
    : scene_(std::move(scene)),
      settings_(settings),
      seed_(seed),
      width_(scene_->scene.camera->width),
      height_(scene_->scene.camera->height),
      tile_(tile_size),
      tiles_x_((width_ + tile_size - 1) / tile_size),
      tiles_y_((height_ + tile_size - 1) / tile_size),
      max_pass_spp_(max_pass_spp),
      adaptive_(adaptive),
      sampler_(sampler),
      k_(sampler.k()) {
  tile_first_.resize(tile_count() + 1);
  size_t ch = 0;
  for (uint32_t t = 0; t < tile_count(); ++t) {
    tile_first_[t] = ch;
    const TileRect r = tile_rect(t);
    ch += 3 * static_cast<size_t>(k_) * static_cast<size_t>(r.w) * static_cast<size_t>(r.h);
  }
  tile_first_[tile_count()] = ch;
  const Camera& c = *scene_->scene.camera;
  cam_pos_ = c.position;
  cam_fwd_ = normalize(c.look_at - c.position);
  cam_right_ = normalize(cross(cam_fwd_, c.up));
  cam_up_ = cross(cam_right_, cam_fwd_);
  tan_half_ = std::tan(0.5 * c.fov_deg * kPi / 180.0);
  aspect_ = static_cast<double>(width_) / static_cast<double>(height_);
}

PassSchedule ImageKernel::schedule() const {
  PassSchedule s;
  s.first_pass_samples = 1;
  s.max_pass_samples = max_pass_spp_;
  // About 16k paths per block: a 32x32 tile gets 16 spp per block.
  s.block_samples = std::max<uint64_t>(1, 16384 / static_cast<uint64_t>(tile_ * tile_));
  if (k_ > 1) {
    // Every pass and block gives each replicate the same number of points.
    s.first_pass_samples = k_;
    s.max_pass_samples = std::max<uint64_t>(k_, max_pass_spp_ / k_ * k_);
    s.block_samples = std::max<uint64_t>(1, s.block_samples / k_) * k_;
    s.sample_quantum = k_;
  }
  // A tile's blocks of one pass merge 4 at a time (PassSchedule::group_blocks): a
  // cluster worker sends a quarter of the per-pixel tallies, and a pass with 8 blocks
  // per tile still has 2 groups per tile to spread over workers.
  s.group_blocks = 4;
  return s;
}

TileRect ImageKernel::tile_rect(uint32_t tile) const {
  const int tx = static_cast<int>(tile) % tiles_x_, ty = static_cast<int>(tile) / tiles_x_;
  TileRect r;
  r.x = tx * tile_;
  r.y = ty * tile_;
  r.w = std::min(tile_, width_ - r.x);
  r.h = std::min(tile_, height_ - r.y);
  return r;
}

size_t ImageKernel::pixel_channel(int x, int y) const {
  const int tx = x / tile_, ty = y / tile_;
  const uint32_t t = static_cast<uint32_t>(ty * tiles_x_ + tx);
  const TileRect r = tile_rect(t);
  return tile_first_[t] +
         3 * static_cast<size_t>(k_) * (static_cast<size_t>(y - r.y) * static_cast<size_t>(r.w) + static_cast<size_t>(x - r.x));
}

ReplicatedEstimate ImageKernel::pixel_estimate(const JobState& state, size_t ch, size_t c) const {
  // The tile whose channel range holds `ch`.
  const auto it = std::upper_bound(tile_first_.begin(), tile_first_.end(), ch);
  return estimate_in(state, static_cast<uint32_t>(it - tile_first_.begin() - 1), ch, c);
}

ReplicatedEstimate ImageKernel::estimate_in(const JobState& state, uint32_t tile, size_t ch, size_t c) const {
  if (k_ <= 1) return combine_replicates(&state.channels[ch + c], 3, k_);
  // Replicate r's mean is its sum over its count; the estimate and its error are those of
  // combine_replicates.
  ReplicatedEstimate e;
  e.n = state.partition_samples[tile];
  e.critical_n = k_;
  const float* sum = &state.sums[ch + c];
  if (e.n < k_) {  // early on (a sample limit under K): the pooled mean, no error bar yet
    double total = 0.0;
    for (uint32_t r = 0; r < e.n; ++r) total += static_cast<double>(sum[3 * static_cast<size_t>(r)]);
    e.mean = e.n > 0 ? total / static_cast<double>(e.n) : 0.0;
    return e;
  }
  return replicate_spread(k_, e.n, [&](uint32_t r) { return static_cast<double>(sum[3 * static_cast<size_t>(r)]) / replicate_count(e.n, r); });
}

bool ImageKernel::upgrade_state(JobState& state) const {
  if (k_ <= 1 || !state.sums.empty() || state.channels.size() != pixel_channels() ||
      state.partition_samples.size() != tile_count()) {
    return false;
  }
  state.sums.resize(state.channels.size());
  for (size_t i = 0; i < state.channels.size(); ++i) {
    state.sums[i] = static_cast<float>(state.channels[i].mean * static_cast<double>(state.channels[i].n));
  }
  std::vector<Tally>().swap(state.channels);
  return true;
}

void ImageKernel::run_block(const Block& block, BlockResult& out) const {
  with_sample_type(sampler_.kind, [&]<class Sample>(std::type_identity<Sample>) { run_pixels<Sample>(block, out); });
}

template <class Sample>
void ImageKernel::run_pixels(const Block& block, BlockResult& out) const {
  const TileRect r = tile_rect(block.partition);
  const size_t tile_channels = 3 * static_cast<size_t>(k_) * static_cast<size_t>(r.w) * static_cast<size_t>(r.h);
  const bool sums = k_ > 1;
  if (sums) {
    out.first_sum = static_cast<uint32_t>(tile_first_[block.partition]);
    out.sums.assign(tile_channels, 0.0);
  } else {
    out.first_channel = static_cast<uint32_t>(tile_first_[block.partition]);
    out.tallies.assign(tile_channels, Tally{});
  }
  const PathTracer& tracer = *scene_->tracer;
  ReplicateRgbSamples v(sums ? 0 : k_, sums ? 0 : block.sample_count);
  ReplicateStreams streams(k_);
  const double inv_w = 1.0 / width_, inv_h = 1.0 / height_;
  for (int y = r.y; y < r.y + r.h; ++y) {
    for (int x = r.x; x < r.x + r.w; ++x) {
      if (block_abandoned()) return;  // its result is dropped (block_abandon.hpp)
      const uint64_t key = stream_key(seed_, static_cast<uint64_t>(y) * static_cast<uint64_t>(width_) + static_cast<uint64_t>(x));
      streams.start(key);
      const size_t base =
          3 * static_cast<size_t>(k_) * (static_cast<size_t>(y - r.y) * static_cast<size_t>(r.w) + static_cast<size_t>(x - r.x));
      double* sum = sums ? &out.sums[base] : nullptr;
      v.clear();
      for (uint64_t i = block.first_sample; i < block.first_sample + block.sample_count; ++i) {
        const Sample rng = streams.sample<Sample>(i);
        const double sx = (2.0 * (x + rng.uniform(0)) * inv_w - 1.0) * tan_half_ * aspect_;
        const double sy = (1.0 - 2.0 * (y + rng.uniform(1)) * inv_h) * tan_half_;
        const Vec3 d = normalize(cam_fwd_ + cam_right_ * sx + cam_up_ * sy);
        const Rgb L = tracer.camera(cam_pos_, d, settings_, rng, 2, out.counters);
        out.counters.add(LightingCounter::evaluations);
        if (!std::isfinite(L.x) || !std::isfinite(L.y) || !std::isfinite(L.z)) {
          out.counters.add(LightingCounter::nonfinite);
          continue;  // a sum counts it as 0; a tally leaves it out
        }
        if (sums) {
          double* s = sum + 3 * static_cast<size_t>(streams.replicate(i));
          s[0] += L.x;
          s[1] += L.y;
          s[2] += L.z;
        } else {
          v.add(streams.replicate(i), L.x, L.y, L.z);
        }
      }
      if (!sums) v.tally_into(&out.tallies[base]);
    }
  }
  if (auto err = take_embree_error()) {
    SampleFault f;
    f.sample_index = block.first_sample;
    f.point = {static_cast<double>(r.x), static_cast<double>(r.y)};
    f.message = *err;
    out.fault = std::move(f);
  }
}

double ImageKernel::image_mean(const JobState& state) const {
  // The plain average of the replicate means (an empty replicate counts as 0).
  double sum = 0;
  if (k_ <= 1) {
    for (const Tally& t : state.channels) sum += t.mean;
  } else {
    for (uint32_t t = 0; t < tile_count(); ++t) {
      const uint64_t n = state.partition_samples[t];
      for (uint32_t r = 0; r < k_ && r < n; ++r) {  // replicate r of every pixel of the tile
        double replicate_sum = 0;
        for (size_t ch = tile_first_[t] + 3 * static_cast<size_t>(r); ch < tile_first_[t + 1]; ch += 3 * static_cast<size_t>(k_)) {
          replicate_sum += static_cast<double>(state.sums[ch]) + static_cast<double>(state.sums[ch + 1]) +
                           static_cast<double>(state.sums[ch + 2]);
        }
        sum += replicate_sum / replicate_count(n, r);
      }
    }
  }
  const size_t n = pixel_channels();
  return n == 0 ? 0.0 : sum / static_cast<double>(n);
}

double ImageKernel::pixel_rel_error(const JobState& state, uint32_t tile, size_t ch, double confidence,
                                    double delta) const {
  // The pixel's RGB average: half-width of its mean over |its mean| + delta.
  thread_local CriticalCache critical;
  double half = 0, mean = 0;
  for (size_t c = 0; c < 3; ++c) {
    const ReplicatedEstimate e = estimate_in(state, tile, ch, c);
    if (!e.has_error()) return std::numeric_limits<double>::infinity();
    half += critical(confidence, e.critical_n) * e.std_error;
    mean += std::fabs(e.mean);
  }
  return half / (mean + 3 * delta);
}

std::vector<uint32_t> ImageKernel::active_partitions(const JobState& state) const {
  if (!adaptive_) return Kernel::active_partitions(state);
  const double delta = std::max(1e-3 * std::fabs(image_mean(state)), std::numeric_limits<double>::min());
  std::vector<uint32_t> active;
  for (uint32_t t = 0; t < tile_count(); ++t) {
    bool need = state.partition_samples[t] < adaptive_->min_spp;
    for (size_t ch = tile_first_[t]; !need && ch < tile_first_[t + 1]; ch += 3 * static_cast<size_t>(k_)) {
      need = pixel_rel_error(state, t, ch, 0.95, delta) > adaptive_->rel_error;
    }
    if (need) active.push_back(t);
  }
  return active;
}

ErrorSummary ImageKernel::error_summary(const JobState& state, double confidence) const {
  constexpr double inf = std::numeric_limits<double>::infinity();
  const double mean = image_mean(state);
  const double delta = std::max(1e-3 * std::fabs(mean), std::numeric_limits<double>::min());
  CriticalCache critical;
  double sum_h = 0, sum_r = 0;
  uint64_t n_min = std::numeric_limits<uint64_t>::max();
  size_t count = 0;
  for (uint32_t t = 0; t < tile_count(); ++t) {
    for (size_t ch = tile_first_[t]; ch < tile_first_[t + 1]; ch += 3 * static_cast<size_t>(k_)) {
      for (size_t c = 0; c < 3; ++c) {
        const ReplicatedEstimate e = estimate_in(state, t, ch, c);
        if (!e.has_error()) return {inf, inf, std::numeric_limits<double>::quiet_NaN(), mean};
        const double half = critical(confidence, e.critical_n) * e.std_error;
        sum_h += half;
        sum_r += half / (std::fabs(e.mean) + delta);
        n_min = std::min(n_min, e.n);
        ++count;
      }
    }
  }
  if (count == 0) return {inf, inf, std::numeric_limits<double>::quiet_NaN(), mean};
  ErrorSummary e;
  e.abs_error = sum_h / static_cast<double>(count);
  e.rel_error = sum_r / static_cast<double>(count);
  // sigma such that z sigma / sqrt(n) = abs_error, and mean such that abs/mean = rel:
  // the engine's 1/sqrt(n) prediction of the samples still needed is then exact for
  // both kinds of target. With replicates the critical value is fixed (K - 1 dof) and
  // the engine's z is the normal one; under RQMC the error falls faster than 1/sqrt(n),
  // so the prediction errs on the side of more samples.
  e.sigma = e.abs_error * std::sqrt(static_cast<double>(n_min)) /
            critical_value(confidence, k_ > 1 ? std::numeric_limits<uint64_t>::max() : n_min);
  e.mean = e.rel_error > 0 ? e.abs_error / e.rel_error : mean;
  return e;
}

std::optional<Headline> ImageKernel::headline(const JobState& state) const {
  // Pixels are estimated independently: the variance of the average is the sum of the
  // channels' squared standard errors over count^2.
  double sum = 0.0, var = 0.0;
  size_t count = 0;
  for (uint32_t t = 0; t < tile_count(); ++t) {
    for (size_t ch = tile_first_[t]; ch < tile_first_[t + 1]; ch += 3 * static_cast<size_t>(k_)) {
      for (size_t c = 0; c < 3; ++c) {
        const ReplicatedEstimate e = estimate_in(state, t, ch, c);
        sum += e.mean;
        if (e.has_error()) var += e.std_error * e.std_error;
        ++count;
      }
    }
  }
  const double n = static_cast<double>(std::max<size_t>(1, count));
  return Headline{sum / n, std::sqrt(var) / n};
}

ImageSnapshot ImageKernel::snapshot(const JobState& state, const TileRect& rect) const {
  ImageSnapshot s;
  s.x0 = std::clamp(rect.x, 0, width_);
  s.y0 = std::clamp(rect.y, 0, height_);
  s.width = std::clamp(rect.w, 0, width_ - s.x0);
  s.height = std::clamp(rect.h, 0, height_ - s.y0);
  s.full_width = width_;
  s.full_height = height_;
  const size_t n = static_cast<size_t>(s.width) * static_cast<size_t>(s.height);
  s.rgb.resize(3 * n);
  s.stderr_rgb.resize(3 * n);
  s.samples.resize(n);
  for (int y = 0; y < s.height; ++y) {
    for (int x = 0; x < s.width; ++x) {
      const int px = s.x0 + x, py = s.y0 + y;
      const size_t ch = pixel_channel(px, py);
      const auto tile = static_cast<uint32_t>((py / tile_) * tiles_x_ + px / tile_);
      const size_t i = static_cast<size_t>(y) * static_cast<size_t>(s.width) + static_cast<size_t>(x);
      for (size_t c = 0; c < 3; ++c) {
        const ReplicatedEstimate e = estimate_in(state, tile, ch, c);
        s.rgb[3 * i + c] = static_cast<float>(e.mean);
        s.stderr_rgb[3 * i + c] = e.has_error() ? static_cast<float>(e.std_error) : 0.0f;
        if (c == 0) s.samples[i] = static_cast<float>(e.n);
      }
    }
  }
  return s;
}

}  // namespace tally
