#pragma once
// Counter-based random numbers: every uniform is a pure function of
// (seed, stream, sample index, dimension). No generator state is shared between
// samples, so results do not depend on thread count, chunking or evaluation order,
// and a resumed job draws exactly the numbers an uninterrupted one would.
#include <cstdint>

namespace tally {

// SplitMix64's output function (Stafford's "Mix13"): a bijective 64-bit mixer whose
// outputs for consecutive inputs pass BigCrush (it is SplitMix64 itself).
constexpr uint64_t mix64(uint64_t z) noexcept {
  z ^= z >> 30;
  z *= 0xbf58476d1ce4e5b9ULL;
  z ^= z >> 27;
  z *= 0x94d049bb133111ebULL;
  z ^= z >> 31;
  return z;
}

inline constexpr uint64_t kGolden64 = 0x9e3779b97f4a7c15ULL;

// 53 random bits -> [0, 1). The largest value is 1 - 2^-53, never 1.
constexpr double to_unit_double(uint64_t bits) noexcept {
  return static_cast<double>(static_cast<int64_t>(bits >> 11)) * 0x1.0p-53;
}
// 53 random bits -> (0, 1), the centre of one of 2^53 equal cells: never 0 or 1,
// so 1/x, log(x) and inverse CDFs with poles at the ends stay finite.
constexpr double to_open_unit_double(uint64_t bits) noexcept {
  return (static_cast<double>(static_cast<int64_t>(bits >> 11)) + 0.5) * 0x1.0p-53;
}
// 24 random bits -> [0, 1) in float. The largest value is 1 - 2^-24.
constexpr float to_unit_float(uint64_t bits) noexcept {
  return static_cast<float>(static_cast<int32_t>(bits >> 40)) * 0x1.0p-24f;
}

// Key of one random stream of a job (e.g. one channel group, one estimator of a
// common-random-numbers comparison, one QMC randomization).
constexpr uint64_t stream_key(uint64_t seed, uint64_t stream) noexcept {
  return mix64(mix64(seed ^ 0x6a09e667f3bcc909ULL) + (stream + 1) * kGolden64);
}

// The random numbers of one sample: uniform(dim) for dim = 0, 1, 2, ...
class SampleRng {
 public:
  // base = SplitMix64's output at position `sample_index` of the stream: a bijection
  // of the index, so no two samples of a stream share a base. Each dimension is then
  // one cheap wyrand step from that base (bits_at). The Monte Carlo loops are bound by
  // this, so it is one full mix per sample and one multiply per uniform.
  constexpr SampleRng(uint64_t stream_key_value, uint64_t sample_index) noexcept
      : base_(sample_base(stream_key_value, sample_index)) {}

  static constexpr uint64_t sample_base(uint64_t stream_key_value, uint64_t sample_index) noexcept {
    return mix64(stream_key_value + sample_index * kGolden64);
  }
  // Dimension `dim` of a sample: wyrand's output function (one 64x64->128 multiply,
  // folded) at the Weyl-sequence state base + (dim + 1) * increment. wyrand passes
  // BigCrush and PractRand; this is the cost that matters in the sampling loops.
  static constexpr uint64_t bits_at(uint64_t base, uint32_t dim) noexcept {
    const uint64_t c = base + (static_cast<uint64_t>(dim) + 1) * 0xa0761d6478bd642fULL;
    return mum(c, c ^ 0xe7037ed1a0b428dbULL);
  }
  static constexpr uint64_t mum(uint64_t a, uint64_t b) noexcept {
    __extension__ using u128 = unsigned __int128;
    const u128 r = static_cast<u128>(a) * b;
    return static_cast<uint64_t>(r) ^ static_cast<uint64_t>(r >> 64);
  }

  constexpr uint64_t bits(uint32_t dim) const noexcept { return bits_at(base_, dim); }
  constexpr double uniform(uint32_t dim) const noexcept { return to_unit_double(bits(dim)); }
  constexpr double open_uniform(uint32_t dim) const noexcept {
    return to_open_unit_double(bits(dim));
  }
  constexpr float uniform_float(uint32_t dim) const noexcept { return to_unit_float(bits(dim)); }

  // Sequential convenience: the next dimension.
  double next() noexcept { return uniform(next_dim_++); }
  float next_float() noexcept { return uniform_float(next_dim_++); }
  uint32_t dims_used() const noexcept { return next_dim_; }

 private:
  uint64_t base_;
  uint32_t next_dim_ = 0;
};

}  // namespace tally
