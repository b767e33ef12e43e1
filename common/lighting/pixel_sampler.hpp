#pragma once
// Which random numbers a pixel (or query point) sample uses.
//
//   independent  SampleRng(stream_key(seed, pixel), i): every uniform independent.
//   sobol        K replicates (independent randomizations) of a shuffled, Owen-scrambled
//                2-D Sobol' sequence per dimension pair (common/sampling/sobol_burley.hpp).
//                Sample i of a pixel belongs to replicate r = i mod K as its point
//                j = i div K; dimensions 2p and 2p+1 are the two coordinates of pair p.
//
// Dimension layout (common/lighting/path_tracer.hpp): pair 0 = the pixel jitter (images);
// then per path vertex three pairs: (light choice, roulette), (light point u, v),
// (direction u, v). Every quantity a 2-D sampling routine maps to a point on the light
// or a direction therefore gets one well-stratified 2-D pair of its own.
//
// Everything is a pure function of (seed, pixel, sample index): any thread count,
// worker count or resume gives the same bits.
#include <cstdint>
#include <type_traits>
#include <vector>

#include "common/rng/counter_rng.hpp"
#include "common/sampling/sobol_burley.hpp"

namespace tally {

enum class SamplerKind { independent, sobol };

// The default K. Images: 4 — at low spp each replicate keeps 4+ points of its net (16-spp
// RMSE 25-36% below K = 8's on the suite) and a pixel holds 12 floats, fewer bytes than
// Cycles; the price is t with 3 dof (intervals 35% wider than t_7's). Point queries: 8 —
// their state is a few numbers a point, and with 4 replicates the intervals of the
// BSDF-sampled estimators under-cover (0.91 / 0.92 for uniform / cosine hemisphere at 128
// samples, QmcCoverage.PointQueriesOverAThousandSeeds; 8 keeps them in [0.93, 0.97]).
// docs/lighting.md, "Replicates: four a pixel, eight a point".
inline constexpr uint32_t kDefaultImageReplicates = 4;
inline constexpr uint32_t kDefaultPointReplicates = 8;

struct SamplerSettings {
  SamplerKind kind = SamplerKind::sobol;
  uint32_t replicates = kDefaultImageReplicates;  // K; always 1 for independent
  uint32_t k() const { return kind == SamplerKind::independent ? 1u : replicates; }
};

// The random numbers of point `index` of one replicate of the Sobol sampler; the same
// interface as SampleRng (uniform(dim) in [0, 1)).
class SobolSample {
 public:
  SobolSample(uint64_t replicate_key, uint64_t index) noexcept : key_(replicate_key), index_(index) {}
  // Key of replicate r of a pixel/point stream.
  static uint64_t replicate_key(uint64_t stream_key_value, uint32_t replicate) noexcept {
    return mix64(stream_key_value ^ mix64(0x5b0b01ULL + replicate));
  }
  // The shuffled index of the last pair is kept: the path tracer asks for 2p and 2p + 1
  // in a row, and a coordinate nobody asks for (e.g. roulette) is never computed.
  double uniform(uint32_t dim) const noexcept {
    const uint32_t pair = dim >> 1;
    if (pair != cached_pair_) {
      point_ = SobolBurleyPoint(mix64(key_ + (static_cast<uint64_t>(pair) + 1) * kGolden64), index_);
      cached_pair_ = pair;
    }
    return point_.coordinate(dim & 1u);
  }

 private:
  uint64_t key_;
  uint64_t index_;
  mutable uint32_t cached_pair_ = ~0u;  // a per-sample object, never shared between threads
  mutable SobolBurleyPoint point_;
};

// The sample streams of one pixel or point: sample i belongs to replicate i mod K and
// draws SampleRng(key, i) (independent) or point i div K of replicate (i mod K)'s
// Sobol sequence. One per block run; start() it for each pixel or point.
class ReplicateStreams {
 public:
  explicit ReplicateStreams(uint32_t replicates) : keys_(replicates) {}
  void start(uint64_t stream_key_value) {
    key_ = stream_key_value;
    for (uint32_t q = 0; q < k(); ++q) keys_[q] = SobolSample::replicate_key(key_, q);
  }
  uint32_t replicate(uint64_t i) const noexcept { return static_cast<uint32_t>(i % k()); }
  template <class Sample>
  Sample sample(uint64_t i) const noexcept {
    if constexpr (std::is_same_v<Sample, SampleRng>) {
      return SampleRng(key_, i);
    } else {
      return SobolSample(keys_[replicate(i)], i / k());
    }
  }

 private:
  uint32_t k() const noexcept { return static_cast<uint32_t>(keys_.size()); }
  uint64_t key_ = 0;
  std::vector<uint64_t> keys_;
};

// Calls f(std::type_identity<SampleRng>{}) or f(std::type_identity<SobolSample>{}):
// a kernel's sample loop is compiled once per sampler.
template <class F>
void with_sample_type(SamplerKind kind, F&& f) {
  if (kind == SamplerKind::independent) {
    f(std::type_identity<SampleRng>{});
  } else {
    f(std::type_identity<SobolSample>{});
  }
}

}  // namespace tally
