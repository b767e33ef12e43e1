#pragma once
// Randomized quasi-Monte Carlo with random access: Owen-scrambled Sobol points.
//
// Choice: Sobol (base 2) over scrambled Halton because base-2 digits make a nested
// uniform (Owen) scramble cheap and exact, and Owen-scrambled Sobol keeps the (t, m, s)-net
// structure, which gives variance O(N^-3 (log N)^(s-1)) for smooth integrands.
// Direction numbers: Joe & Kuo (2008, new-joe-kuo-6.21201), read from Boost 1.74's
// boost/random/detail/sobol_table.hpp rather than typed in; the tests compare the
// unscrambled points with boost::random::sobol.
//
// Scramble: true nested uniform scrambling. Bit b of the 32-bit Sobol coordinate is
// flipped by a random bit that is a pure function of (scramble seed, dimension, b, the
// higher bits above b) computed with the counter RNG's mixer; the 21 bits below the 32
// Sobol bits are filled from the same tree. Hence, over scramble seeds, each point's
// coordinate is exactly uniform on the 2^-53 grid of [0, 1): every randomization is an
// unbiased estimator, and independent seeds give independent replicates for error bars.
// Indices >= 2^32 start a fresh independent scramble per block of 2^32 points.
#include <array>
#include <cstdint>
#include <vector>

namespace tally {

inline constexpr std::uint32_t kRqmcMaxDimensions = 1024;

// Unscrambled Sobol coordinate as 32 fixed-point bits (point index < 2^32, natural
// order, not Gray-code order). dim < kRqmcMaxDimensions, else std::out_of_range.
std::uint32_t sobol_bits(std::uint32_t index, std::uint32_t dim);

// Coordinate `dim` of point `index` of the Owen-scrambled Sobol sequence selected by
// scramble_seed, in [0, 1). dim < kRqmcMaxDimensions, else std::out_of_range.
double rqmc_point(std::uint64_t scramble_seed, std::uint64_t index, std::uint32_t dim);

// Direction numbers of dimension `dim` (v[j] for index bit j, bit 31 = 1/2).
const std::array<std::uint32_t, 32>& sobol_directions(std::uint32_t dim);

// One randomization of a Sobol point set by Matousek's random linear scramble plus a
// random digital shift (the "affine matrix scramble"). Owen (2003, "Variance with
// alternative scramblings of digital nets") shows its variance equals that of the nested
// uniform scramble above for every square-integrable integrand, and each coordinate is
// exactly uniform over scrambles, so each randomization is an unbiased estimator. It is
// far cheaper: the scramble is applied once to the 32 direction numbers of each
// dimension, after which consecutive points in Gray-code order differ by one XOR.
// The first 2^m points in Gray-code order are the same set as in natural order.
class ScrambledSobolSet {
 public:
  ScrambledSobolSet(std::uint64_t scramble_seed, std::uint32_t dims);
  std::uint32_t dimensions() const { return dims_; }
  // Coordinates of points [first, first + n) (Gray-code order, first + n <= 2^32):
  // rows[d][i] in (0, 1).
  void fill(std::uint32_t first, std::size_t n, double* const* rows) const;
  // The same points' 32 scrambled and shifted Sobol' bits of dimension d (fill's
  // coordinate is bits * 2^-32 plus a uniform draw below them).
  void fill_bits(std::uint32_t d, std::uint32_t first, std::size_t n, std::uint32_t* bits) const;

 private:
  std::uint32_t dims_;
  std::vector<std::array<std::uint32_t, 32>> v_;  // scrambled direction numbers
  std::vector<std::uint32_t> shift_;
  std::vector<double> low_;  // below the 32 Sobol bits: uniform in [0, 2^-32)
};

// A higher-order scrambled digital net (Dick 2008, "Walsh spaces containing smooth
// functions and quasi-Monte Carlo rules of arbitrary high order"): the points of a
// ScrambledSobolSet of interlacing x dims dimensions, each coordinate j made of the
// digits of dimensions alpha j .. alpha j + alpha - 1 taken in turn (the first digit of
// each, then the second of each, ...). An order-alpha net integrates functions with
// square-integrable mixed derivatives of order alpha with error O(N^-alpha (log N)^(alpha dims)),
// where the unmixed net gives O(N^-1 (log N)^dims). Interlacing after the affine scramble
// is unbiased (each underlying coordinate is uniform and independent, so each interlaced
// coordinate is uniform), and by Owen (2003) its variance is that of the Owen-scrambled
// net interlaced, for which Goda & Dick (2015) show RMSE O(N^(-alpha - 1/2 + eps)).
// Interlacing 2 keeps all 32 bits of both (64, then the top 52); 3 the top 21 of each
// (63, then the top 52). Coordinates are the midpoints of the 2^-52 grid.
class InterlacedSobolSet {
 public:
  // interlacing in {2, 3}; interlacing x dims <= kRqmcMaxDimensions.
  InterlacedSobolSet(std::uint64_t scramble_seed, std::uint32_t dims, std::uint32_t interlacing);
  std::uint32_t dimensions() const { return dims_; }
  std::uint32_t interlacing() const { return alpha_; }
  // As ScrambledSobolSet::fill: rows[d][i] in (0, 1).
  void fill(std::uint32_t first, std::size_t n, double* const* rows) const;

 private:
  std::uint32_t dims_, alpha_;
  ScrambledSobolSet base_;
};

// The digits of the alpha (2 or 3) 32-bit words in turn, most significant first, as the
// top 52 bits of a [0, 1) fixed-point number (InterlacedSobolSet's coordinate, before the
// half grid step it adds).
std::uint64_t interlace_digits(const std::uint32_t* words, std::uint32_t alpha);

}  // namespace tally
