#include "common/lighting/point_kernel.hpp"

#include <chrono>
#include <cmath>
#include <limits>
#include <type_traits>

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
  if (sampler_.kind == SamplerKind::independent) {
    run_samples<SampleRng>(block, out);
  } else {
    run_samples<SobolSample>(block, out);
  }
}

template <class Sample>
void PointKernel::run_samples(const Block& block, BlockResult& out) const {
  out.first_channel = 0;
  out.tallies.assign(channel_count(), Tally{});
  const PathTracer& tracer = *scene_->tracer;
  std::vector<std::vector<double>> v(3 * static_cast<size_t>(k_));  // [replicate * 3 + rgb]
  for (auto& a : v) a.reserve(block.sample_count / k_ + 1);
  std::vector<uint64_t> rep_keys(k_);
  for (size_t k = 0; k < points_.size(); ++k) {
    const uint64_t key = stream_key(seed_, k);
    for (uint32_t q = 0; q < k_; ++q) rep_keys[q] = SobolSample::replicate_key(key, q);
    const QueryPoint& q = points_[k];
    for (size_t e = 0; e < strategies_.size(); ++e) {
      const PathSettings settings{strategies_[e], max_depth_, rr_};
      for (auto& a : v) a.clear();
      const auto t0 = std::chrono::steady_clock::now();
      for (uint64_t i = block.first_sample; i < block.first_sample + block.sample_count; ++i) {
        const uint32_t rep = static_cast<uint32_t>(i % k_);
        // The same numbers for every estimator.
        const Sample rng = [&] {
          if constexpr (std::is_same_v<Sample, SampleRng>) {
            return SampleRng(key, i);
          } else {
            return SobolSample(rep_keys[rep], i / k_);
          }
        }();
        const Rgb L = q.emission + tracer.reflected(q.vertex, settings, rng, 0, out.counters);
        out.counters.add(LightingCounter::evaluations);
        if (!std::isfinite(L.x) || !std::isfinite(L.y) || !std::isfinite(L.z)) {
          out.counters.add(LightingCounter::nonfinite);  // excluded, never merged
          continue;
        }
        v[3 * rep].push_back(L.x);
        v[3 * rep + 1].push_back(L.y);
        v[3 * rep + 2].push_back(L.z);
        // The tail tracker counts channel 0's samples: replicate 0 of estimator 0, point 0.
        if (e == 0 && k == 0 && rep == 0) out.tail.offer(std::fabs(L.x));
      }
      const auto t1 = std::chrono::steady_clock::now();
      nanos_[e].fetch_add(static_cast<uint64_t>(std::chrono::duration_cast<std::chrono::nanoseconds>(t1 - t0).count()),
                          std::memory_order_relaxed);
      samples_[e].fetch_add(block.sample_count, std::memory_order_relaxed);
      for (uint32_t rep = 0; rep < k_; ++rep) {
        for (int c = 0; c < 3; ++c) {
          const auto& a = v[3 * rep + static_cast<size_t>(c)];
          out.tallies[channel(e, k, c, rep)] = Tally::from_batch(a.data(), a.size());
        }
      }
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
