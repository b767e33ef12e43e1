#include "common/sampling/qmc.hpp"

#include <array>
#include <stdexcept>
#include <string>
#include <vector>

#include <boost/random/detail/sobol_table.hpp>

#include "common/rng/counter_rng.hpp"

namespace tally {
namespace {

using SobolTable = boost::random::detail::qrng_tables::sobol;
static_assert(kRqmcMaxDimensions <= SobolTable::max_dimension);

// Direction numbers v[dim][j] for index bit j, as 32-bit fixed point (bit 31 = 1/2).
// Dimension 0 is van der Corput; dimension d >= 1 uses primitive polynomial d - 1 with
// the Bratley-Fox recurrence m_j = 2 a_1 m_{j-1} ^ 4 a_2 m_{j-2} ^ ... ^ 2^s m_{j-s} ^ m_{j-s}.
std::vector<std::array<std::uint32_t, 32>> build_directions() {
  std::vector<std::array<std::uint32_t, 32>> v(kRqmcMaxDimensions);
  for (std::uint32_t j = 0; j < 32; ++j) v[0][j] = 1u << (31 - j);
  for (std::uint32_t d = 1; d < kRqmcMaxDimensions; ++d) {
    const std::uint32_t poly = SobolTable::polynomial(d - 1);
    std::uint32_t degree = 0;
    while ((poly >> (degree + 1)) != 0) ++degree;  // polynomial degree = msb position
    std::array<std::uint32_t, 32> m{};
    for (std::uint32_t j = 0; j < degree && j < 32; ++j) m[j] = SobolTable::minit(d - 1, j);
    for (std::uint32_t j = degree; j < 32; ++j) {
      std::uint32_t mj = m[j - degree];
      for (std::uint32_t k = 0; k < degree; ++k) {
        // Bit k of poly multiplies m_{j-(degree-k)} by 2^(degree-k) (bit 0 is the
        // constant term, always 1, giving the 2^s m_{j-s} term).
        const std::uint32_t shift = degree - k;
        if ((poly >> k) & 1u) mj ^= m[j - shift] << shift;
      }
      m[j] = mj;
    }
    for (std::uint32_t j = 0; j < 32; ++j) v[d][j] = m[j] << (31 - j);
  }
  return v;
}

const std::vector<std::array<std::uint32_t, 32>>& directions() {
  static const std::vector<std::array<std::uint32_t, 32>> table = build_directions();
  return table;
}

void check_dim(std::uint32_t dim) {
  if (dim >= kRqmcMaxDimensions) {
    throw std::out_of_range("rqmc: dimension " + std::to_string(dim) +
                            " >= " + std::to_string(kRqmcMaxDimensions));
  }
}

}  // namespace

std::uint32_t sobol_bits(std::uint32_t index, std::uint32_t dim) {
  check_dim(dim);
  const std::array<std::uint32_t, 32>& v = directions()[dim];
  std::uint32_t x = 0;
  for (std::uint32_t j = 0; index != 0; index >>= 1, ++j) {
    if (index & 1u) x ^= v[j];
  }
  return x;
}

double rqmc_point(std::uint64_t scramble_seed, std::uint64_t index, std::uint32_t dim) {
  const std::uint32_t x = sobol_bits(static_cast<std::uint32_t>(index), dim);
  // Key of this (seed, block of 2^32 points, dimension) scramble tree.
  const std::uint64_t key = stream_key(scramble_seed ^ mix64(index >> 32), dim);
  // Owen scramble: walk the binary tree from the top bit; the node is identified by its
  // depth and the original bits above it (a leading 1 marks the depth), and its random
  // flip bit comes from hashing (key, node).
  std::uint32_t y = 0;
  for (int b = 31; b >= 0; --b) {
    const std::uint64_t prefix = b == 31 ? 0 : (x >> (b + 1));
    const std::uint64_t node = (std::uint64_t{1} << (31 - b)) | prefix;
    const std::uint32_t flip = static_cast<std::uint32_t>(mix64(key ^ mix64(node)) >> 63);
    y |= (((x >> b) & 1u) ^ flip) << b;
  }
  // Below the 32 Sobol bits every point sits alone in its leaf: fill 21 uniform bits from
  // the leaf node (depth 32), completing the scramble to full double resolution.
  const std::uint64_t leaf = (std::uint64_t{1} << 32) | x;
  const std::uint64_t low = mix64(key ^ mix64(leaf) ^ 0x5851f42d4c957f2dULL) >> 43;  // 21 bits
  return static_cast<double>((static_cast<std::uint64_t>(y) << 21) | low) * 0x1.0p-53;
}

const std::array<std::uint32_t, 32>& sobol_directions(std::uint32_t dim) {
  check_dim(dim);
  return directions()[dim];
}

ScrambledSobolSet::ScrambledSobolSet(std::uint64_t scramble_seed, std::uint32_t dims)
    : dims_(dims), v_(dims), shift_(dims), low_(dims) {
  if (dims > 0) check_dim(dims - 1);
  for (std::uint32_t d = 0; d < dims; ++d) {
    const SampleRng rng(stream_key(scramble_seed, 0x4c4d53), d);  // "LMS"
    // Lower-triangular matrix with unit diagonal in digit order: output bit p depends
    // on input bits q >= p. col[q] = bit q plus random bits below it.
    std::array<std::uint32_t, 32> col{};
    for (std::uint32_t q = 0; q < 32; ++q) {
      const auto r = static_cast<std::uint32_t>(rng.bits(q) >> 32);
      const std::uint32_t below = q == 0 ? 0u : (r & ((1u << q) - 1u));
      col[q] = (1u << q) | below;
    }
    const std::array<std::uint32_t, 32>& v = directions()[d];
    for (std::uint32_t j = 0; j < 32; ++j) {
      std::uint32_t y = 0;
      for (std::uint32_t q = 0; q < 32; ++q) {
        if ((v[j] >> q) & 1u) y ^= col[q];
      }
      v_[d][j] = y;
    }
    shift_[d] = static_cast<std::uint32_t>(rng.bits(32) >> 32);
    low_[d] = to_open_unit_double(rng.bits(33)) * 0x1.0p-32;
  }
}

namespace {

// Calls out(i, y) with the scrambled bits y of points first .. first + n - 1 of one
// dimension (direction numbers v, digital shift `shift`), in Gray-code order.
template <class Out>
void walk_gray(const std::array<std::uint32_t, 32>& v, std::uint32_t shift, std::uint32_t first, std::size_t n,
               Out out) {
  // Point `first` directly: y = shift ^ XOR of v[k] over the bits of gray(first).
  const std::uint32_t g = first ^ (first >> 1);
  std::uint32_t y = shift;
  for (std::uint32_t k = 0; k < 32; ++k) {
    if ((g >> k) & 1u) y ^= v[k];
  }
  for (std::size_t i = 0; i < n; ++i) {
    out(i, y);
    // Gray code: the next point flips the direction of the lowest set bit of j + 1.
    const auto next = static_cast<std::uint32_t>(first + i + 1);
    y ^= v[static_cast<std::uint32_t>(__builtin_ctz(next | 0x80000000u))];
  }
}

// Bits 0..31 of x to the even bits 0..62 (bit k to 2k).
std::uint64_t spread2(std::uint32_t x) {
  std::uint64_t v = x;
  v = (v | (v << 16)) & 0x0000FFFF0000FFFFULL;
  v = (v | (v << 8)) & 0x00FF00FF00FF00FFULL;
  v = (v | (v << 4)) & 0x0F0F0F0F0F0F0F0FULL;
  v = (v | (v << 2)) & 0x3333333333333333ULL;
  v = (v | (v << 1)) & 0x5555555555555555ULL;
  return v;
}

// Bits 0..20 of x to every third bit 0..60 (bit k to 3k).
std::uint64_t spread3(std::uint32_t x) {
  std::uint64_t v = x & 0x1FFFFFu;
  v = (v | (v << 32)) & 0x1F00000000FFFFULL;
  v = (v | (v << 16)) & 0x1F0000FF0000FFULL;
  v = (v | (v << 8)) & 0x100F00F00F00F00FULL;
  v = (v | (v << 4)) & 0x10C30C30C30C30C3ULL;
  v = (v | (v << 2)) & 0x1249249249249249ULL;
  return v;
}

}  // namespace

void ScrambledSobolSet::fill(std::uint32_t first, std::size_t n, double* const* rows) const {
  for (std::uint32_t d = 0; d < dims_; ++d) {
    double* row = rows[d];
    const double low = low_[d];
    walk_gray(v_[d], shift_[d], first, n,
              [&](std::size_t i, std::uint32_t y) { row[i] = static_cast<double>(y) * 0x1.0p-32 + low; });
  }
}

void ScrambledSobolSet::fill_bits(std::uint32_t d, std::uint32_t first, std::size_t n, std::uint32_t* bits) const {
  walk_gray(v_[d], shift_[d], first, n, [&](std::size_t i, std::uint32_t y) { bits[i] = y; });
}

std::uint64_t interlace_digits(const std::uint32_t* words, std::uint32_t alpha) {
  if (alpha == 2) return ((spread2(words[0]) << 1) | spread2(words[1])) >> 12;
  // alpha 3: the top 21 bits of each, 63 bits, of which the top 52.
  return ((spread3(words[0] >> 11) << 2) | (spread3(words[1] >> 11) << 1) | spread3(words[2] >> 11)) >> 11;
}

InterlacedSobolSet::InterlacedSobolSet(std::uint64_t scramble_seed, std::uint32_t dims, std::uint32_t interlacing)
    : dims_(dims), alpha_(interlacing), base_(scramble_seed, dims * interlacing) {
  if (interlacing != 2 && interlacing != 3) {
    throw std::invalid_argument("interlacing must be 2 or 3, not " + std::to_string(interlacing));
  }
}

void InterlacedSobolSet::fill(std::uint32_t first, std::size_t n, double* const* rows) const {
  thread_local std::vector<std::uint32_t> bits;
  bits.resize(n * alpha_);
  std::array<std::uint32_t, 3> words{};
  for (std::uint32_t j = 0; j < dims_; ++j) {
    for (std::uint32_t a = 0; a < alpha_; ++a) base_.fill_bits(j * alpha_ + a, first, n, bits.data() + a * n);
    double* row = rows[j];
    for (std::size_t i = 0; i < n; ++i) {
      for (std::uint32_t a = 0; a < alpha_; ++a) words[a] = bits[a * n + i];
      // The midpoint of its 2^-52 cell: exact, and never 0 or 1.
      row[i] = (static_cast<double>(interlace_digits(words.data(), alpha_)) + 0.5) * 0x1.0p-52;
    }
  }
}

}  // namespace tally
