#include "common/lighting/point_kernel.hpp"

#include <chrono>
#include <cmath>

#include "common/lighting/embree_device.hpp"

namespace tally {

PointKernel::PointKernel(std::shared_ptr<const CompiledScene> scene, std::vector<QueryPoint> points,
                         std::vector<Strategy> strategies, int max_depth, bool russian_roulette, uint64_t seed)
    : scene_(std::move(scene)),
      points_(std::move(points)),
      strategies_(std::move(strategies)),
      max_depth_(max_depth),
      rr_(russian_roulette),
      seed_(seed),
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
  s.first_pass_samples = s.block_samples;
  s.max_pass_samples = s.block_samples * 512;
  return s;
}

double PointKernel::seconds_per_sample(size_t e) const {
  const uint64_t n = samples_[e].load(std::memory_order_relaxed);
  return n > 0 ? 1e-9 * static_cast<double>(nanos_[e].load(std::memory_order_relaxed)) / static_cast<double>(n) : 0.0;
}

void PointKernel::run_block(const Block& block, BlockResult& out) const {
  out.first_channel = 0;
  out.tallies.assign(channel_count(), Tally{});
  const PathTracer& tracer = *scene_->tracer;
  std::vector<double> r, g, b;
  r.reserve(block.sample_count);
  g.reserve(block.sample_count);
  b.reserve(block.sample_count);
  for (size_t k = 0; k < points_.size(); ++k) {
    const uint64_t key = stream_key(seed_, k);
    const QueryPoint& q = points_[k];
    for (size_t e = 0; e < strategies_.size(); ++e) {
      const PathSettings settings{strategies_[e], max_depth_, rr_};
      r.clear();
      g.clear();
      b.clear();
      const auto t0 = std::chrono::steady_clock::now();
      for (uint64_t i = block.first_sample; i < block.first_sample + block.sample_count; ++i) {
        const SampleRng rng(key, i);  // the same numbers for every estimator
        const Rgb L = q.emission + tracer.reflected(q.vertex, settings, rng, 0, out.counters);
        out.counters.add(Counter::evaluations);
        if (!std::isfinite(L.x) || !std::isfinite(L.y) || !std::isfinite(L.z)) {
          out.counters.add(Counter::nonfinite);  // excluded, never merged
          continue;
        }
        r.push_back(L.x);
        g.push_back(L.y);
        b.push_back(L.z);
        if (e == 0 && k == 0) out.tail.offer(std::fabs(L.x));
      }
      const auto t1 = std::chrono::steady_clock::now();
      nanos_[e].fetch_add(static_cast<uint64_t>(std::chrono::duration_cast<std::chrono::nanoseconds>(t1 - t0).count()),
                          std::memory_order_relaxed);
      samples_[e].fetch_add(block.sample_count, std::memory_order_relaxed);
      out.tallies[channel(e, k, 0)] = Tally::from_batch(r.data(), r.size());
      out.tallies[channel(e, k, 1)] = Tally::from_batch(g.data(), g.size());
      out.tallies[channel(e, k, 2)] = Tally::from_batch(b.data(), b.size());
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
