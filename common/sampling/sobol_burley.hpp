#pragma once
// Shuffled, Owen-scrambled 2-D Sobol' points with random access (Burley 2020,
// "Practical Hash-based Owen Scrambling", JCGT 9(4); Cycles' "Sobol-Burley" pattern).
//
// One 2-D sequence per (pixel, replicate, dimension pair): point j of the pair is
//   j' = owen(j)                       -- shuffle: a nested scramble of the index bits
//   (x, y) = (sobol_0(j'), sobol_1(j')) -- the first two Sobol' dimensions, a (0,2)-sequence
//   (x, y) = (owen(x), owen(y))        -- independent nested scrambles of each coordinate
// and 21 more random bits below the 32 Sobol' bits, hashed from the scrambled prefix, so
// a coordinate is uniform on the 2^-53 grid of [0, 1).
//
// Why each part:
// * Both coordinates of a pair come from one (0,2)-sequence: the first 2^m points of a
//   pair (and every aligned block of 2^m) have exactly one point in each elementary
//   interval of area 2^-m (tests/sampling/sobol_burley_test.cpp checks all of them).
// * The scramble is a "nested" permutation: bit b of the output depends only on bits
//   >= b of the input (adds and multiplies by even constants carry upwards in the
//   bit-reversed word). Such permutations keep the net property, and with a uniformly
//   random seed added first every coordinate is exactly uniform: each randomization is
//   an unbiased estimator, and randomizations with independent seeds are independent.
// * The index shuffle is the same kind of permutation applied to the index: the first
//   2^m indices map onto one aligned block of 2^m Sobol' indices (the higher index bits
//   are flipped by a constant), which is again a (0, m, 2)-net. With a different shuffle
//   per pair, pairs are decorrelated from each other (padding), so a path of any length
//   uses only the first two Sobol' dimensions, whose 2-D projection is the best there is.
//
// The per-coordinate cost is a handful of multiplies (no tables beyond 32 words).
#include <array>
#include <cstddef>
#include <cstdint>

#include "common/rng/counter_rng.hpp"

namespace tally {

namespace sobol_burley {

constexpr uint32_t reverse_bits(uint32_t x) noexcept {
  x = __builtin_bswap32(x);
  x = ((x >> 4) & 0x0f0f0f0fu) | ((x & 0x0f0f0f0fu) << 4);
  x = ((x >> 2) & 0x33333333u) | ((x & 0x33333333u) << 2);
  return ((x >> 1) & 0x55555555u) | ((x & 0x55555555u) << 1);
}

// Burley's improved Laine-Karras hash: a bijection of 32-bit words whose output bit k
// depends on input bits <= k only.
constexpr uint32_t laine_karras(uint32_t x, uint32_t seed) noexcept {
  x += seed;
  x ^= x * 0x6c50b47cu;
  x ^= x * 0xb82f1e52u;
  x ^= x * 0xc7afe638u;
  x ^= x * 0x8d22f6e6u;
  return x;
}

// Nested uniform (Owen) scramble of a 32-bit fixed-point fraction.
constexpr uint32_t owen_scramble(uint32_t x, uint32_t seed) noexcept {
  return reverse_bits(laine_karras(reverse_bits(x), seed));
}

// Generator matrix columns of Sobol' dimension 1 (Pascal's triangle mod 2), and the same
// bit-reversed.
constexpr std::array<uint32_t, 32> dim1_directions(bool reversed) noexcept {
  std::array<uint32_t, 32> v{};
  uint32_t c = 1u << 31;
  for (int j = 0; j < 32; ++j) {
    v[static_cast<std::size_t>(j)] = reversed ? reverse_bits(c) : c;
    c ^= c >> 1;
  }
  return v;
}
inline constexpr std::array<uint32_t, 32> kDim1 = dim1_directions(false);
inline constexpr std::array<uint32_t, 32> kDim1Reversed = dim1_directions(true);

constexpr uint32_t sobol0(uint32_t index) noexcept { return reverse_bits(index); }
constexpr uint32_t sobol1(uint32_t index) noexcept {
  uint32_t x = 0;
  for (uint32_t j = 0; index != 0; index >>= 1, ++j) {
    if (index & 1u) x ^= kDim1[j];
  }
  return x;
}
// reverse_bits(sobol1(index)) by four byte tables: no data-dependent branches (a bit
// loop mispredicts on random index bits and cost ~10x more).
constexpr std::array<std::array<uint32_t, 256>, 4> dim1_reversed_tables() noexcept {
  std::array<std::array<uint32_t, 256>, 4> t{};
  for (std::size_t b = 0; b < 4; ++b) {
    for (std::size_t byte = 0; byte < 256; ++byte) {
      uint32_t x = 0;
      for (std::size_t k = 0; k < 8; ++k) {
        if ((byte >> k) & 1u) x ^= kDim1Reversed[8 * b + k];
      }
      t[b][byte] = x;
    }
  }
  return t;
}
inline constexpr std::array<std::array<uint32_t, 256>, 4> kDim1ReversedTables = dim1_reversed_tables();

constexpr uint32_t sobol1_reversed(uint32_t index) noexcept {
  return kDim1ReversedTables[0][index & 255u] ^ kDim1ReversedTables[1][(index >> 8) & 255u] ^
         kDim1ReversedTables[2][(index >> 16) & 255u] ^ kDim1ReversedTables[3][index >> 24];
}

}  // namespace sobol_burley

// Point `index` of the 2-D sequence keyed by `pair_key` (a 64-bit hash of seed, pixel,
// replicate and pair), one coordinate at a time:
//   SobolBurleyPoint p(pair_key, index);  p.coordinate(0), p.coordinate(1)  in [0, 1).
// Equal to owen(sobol0(j'), s_x), owen(sobol1(j'), s_y) with j' = owen(index, s_shuffle),
// computed with the bit reversals folded (sobol0 is a reversal itself). Indices >= 2^32
// start an independent sequence per block of 2^32.
class SobolBurleyPoint {
 public:
  SobolBurleyPoint() = default;
  SobolBurleyPoint(uint64_t pair_key, uint64_t index) noexcept
      : h_(index >> 32 ? mix64(pair_key ^ mix64(index >> 32)) : pair_key),
        j_(sobol_burley::owen_scramble(static_cast<uint32_t>(index), static_cast<uint32_t>(h_))) {}

  double coordinate(uint32_t component) const noexcept {
    using namespace sobol_burley;
    const uint64_t h2 = mix64(h_ ^ (component == 0 ? 0x2545f4914f6cdd1dULL : 0x9fb21c651e98df25ULL));
    const uint32_t x = component == 0 ? reverse_bits(laine_karras(j_, static_cast<uint32_t>(h_ >> 32)))
                                      : reverse_bits(laine_karras(sobol1_reversed(j_), static_cast<uint32_t>(h2)));
    // Below the 32 Sobol' bits each point is alone in its cell: 21 uniform bits hashed
    // from the scrambled prefix complete the nested scramble.
    const uint64_t low = SampleRng::mum(h2 ^ x, 0xe7037ed1a0b428dbULL) >> 43;
    return static_cast<double>((static_cast<uint64_t>(x) << 21) | low) * 0x1.0p-53;
  }

 private:
  uint64_t h_ = 0;
  uint32_t j_ = 0;
};

}  // namespace tally
