#include "common/lighting/point_kernel.hpp"

#include <chrono>
#include <cmath>
#include <limits>
#include <type_traits>

#include "common/engine/block_abandon.hpp"
#include "common/stats/confidence.hpp"

#include "common/lighting/embree_device.hpp"

namespace tally {

PointKernel::PointKernel(std::shared_ptr<const CompiledScene> scene, std::vector<QueryPoint> points,
                         std::vector<Strategy> strategies, int max_depth, bool russian_roulette, uint64_t seed,
                         SamplerSettings sampler)
    : scene_(std::move(scene)),
      points_(std::move(points)),
      strategies_(std::move(strategies)),
      max_depth_(max_depth),
      rr_(russian_roulette),
      seed_(seed),
      sampler_(sampler),
      k_(sampler.k()),
      nanos_(new std::atomic<uint64_t>[strategies_.size()]),
      samples_(new std::atomic<uint64_t>[strategies_.size()]) {
  for (size_t e = 0; e < strategies_.size(); ++e) {
    nanos_[e] = 0;
    samples_[e] = 0;
  }
}

PassSchedule PointKernel::schedule() const {
  PassSchedule s;
  const uint64_t work = std::max<uint64_t>(1, points_.size() * strategies_.size());
  s.block_samples = std::max<uint64_t>(64, 8192 / work);
  if (k_ > 1) {  // every block gives each replicate the same number of points
    s.block_samples = (s.block_samples + k_ - 1) / k_ * k_;
    s.sample_quantum = k_;
  }
  s.first_pass_samples = s.block_samples;
  s.max_pass_samples = s.block_samples * 512;
  s.group_blocks = 16;  // results merge 16 blocks at a time (PassSchedule::group_blocks)
  return s;
}

std::optional<Headline> PointKernel::headline(const JobState& state) const {
  const ReplicatedEstimate e = estimate(state, 0, 0, 0);
  return Headline{e.mean, e.has_error() ? e.std_error : std::numeric_limits<double>::quiet_NaN(),
                  std::max<uint64_t>(e.critical_n, 2)};
}

ErrorSummary PointKernel::error_summary(const JobState& state, double confidence) const {
  constexpr double inf = std::numeric_limits<double>::infinity();
  ErrorSummary worst;
  bool any = false;
  for (size_t e = 0; e < strategies_.size(); ++e) {
    for (size_t k = 0; k < points_.size(); ++k) {
      for (int c = 0; c < 3; ++c) {
        const ReplicatedEstimate est = estimate(state, e, k, c);
        if (!est.has_error() || est.n < 2) return {inf, inf, std::numeric_limits<double>::quiet_NaN(), est.mean};
        const double half = est.half_width(confidence);
        const double rel = est.mean != 0.0 ? half / std::fabs(est.mean) : (half == 0.0 ? 0.0 : inf);
        if (!any || half > worst.abs_error) {
          worst.abs_error = half;
          // The engine predicts with z sigma / sqrt(n) (normal z): sigma reproduces this
          // half-width at the current n.
          worst.sigma = half * std::sqrt(static_cast<double>(est.n)) /
                        critical_value(confidence, std::numeric_limits<uint64_t>::max());
          worst.mean = est.mean;
        }
        if (!any || rel > worst.rel_error) worst.rel_error = rel;
        any = true;
      }
    }
  }
  if (!any) return {inf, inf, std::numeric_limits<double>::quiet_NaN(), 0.0};
  return worst;
}

double PointKernel::seconds_per_sample(size_t e) const {
  const uint64_t n = samples_[e].load(std::memory_order_relaxed);
  return n > 0 ? 1e-9 * static_cast<double>(nanos_[e].load(std::memory_order_relaxed)) / static_cast<double>(n) : 0.0;
}

void PointKernel::run_block(const Block& block, BlockResult& out) const {
  with_sample_type(sampler_.kind, [&]<class Sample>(std::type_identity<Sample>) { run_samples<Sample>(block, out); });
}

template <class Sample>
void PointKernel::run_samples(const Block& block, BlockResult& out) const {
  out.first_channel = 0;
  out.tallies.assign(channel_count(), Tally{});
  const PathTracer& tracer = *scene_->tracer;
  ReplicateRgbSamples v(k_, block.sample_count);
  ReplicateStreams streams(k_);
  for (size_t k = 0; k < points_.size(); ++k) {
    streams.start(stream_key(seed_, k));
    const QueryPoint& q = points_[k];
    for (size_t e = 0; e < strategies_.size(); ++e) {
      if (block_abandoned()) return;  // its result is dropped (block_abandon.hpp)
      const PathSettings settings{strategies_[e], max_depth_, rr_};
      v.clear();
      const auto t0 = std::chrono::steady_clock::now();
      for (uint64_t i = block.first_sample; i < block.first_sample + block.sample_count; ++i) {
        const uint32_t rep = streams.replicate(i);
        // The same numbers for every estimator.
        const Sample rng = streams.sample<Sample>(i);
        const Rgb L = q.emission + tracer.reflected(q.vertex, settings, rng, 0, out.counters);
        out.counters.add(LightingCounter::evaluations);
        if (!std::isfinite(L.x) || !std::isfinite(L.y) || !std::isfinite(L.z)) {
          out.counters.add(LightingCounter::nonfinite);  // excluded, never merged
          continue;
        }
        v.add(rep, L.x, L.y, L.z);
        // The tail tracker counts channel 0's samples: replicate 0 of estimator 0, point 0.
        if (e == 0 && k == 0 && rep == 0) out.tail.offer(std::fabs(L.x));
      }
      const auto t1 = std::chrono::steady_clock::now();
      nanos_[e].fetch_add(static_cast<uint64_t>(std::chrono::duration_cast<std::chrono::nanoseconds>(t1 - t0).count()),
                          std::memory_order_relaxed);
      samples_[e].fetch_add(block.sample_count, std::memory_order_relaxed);
      v.tally_into(&out.tallies[channel(e, k, 0)]);  // replicate r's rgb c is channel(e, k, c, r)
    }
  }
  if (auto err = take_embree_error()) {
    SampleFault f;
    f.sample_index = block.first_sample;
    f.message = *err;
    out.fault = std::move(f);
  }
}

}  // namespace tally
