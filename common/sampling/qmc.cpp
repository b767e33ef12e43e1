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

void ScrambledSobolSet::fill(std::uint32_t first, std::size_t n, double* const* rows) const {
  for (std::uint32_t d = 0; d < dims_; ++d) {
    const std::array<std::uint32_t, 32>& v = v_[d];
    // Point `first` directly: y = shift ^ XOR of v[k] over the bits of gray(first).
    const std::uint32_t g = first ^ (first >> 1);
    std::uint32_t y = shift_[d];
    for (std::uint32_t k = 0; k < 32; ++k) {
      if ((g >> k) & 1u) y ^= v[k];
    }
    double* row = rows[d];
    const double low = low_[d];
    for (std::size_t i = 0; i < n; ++i) {
      row[i] = static_cast<double>(y) * 0x1.0p-32 + low;
      // Gray code: the next point flips the direction of the lowest set bit of j + 1.
      const auto next = static_cast<std::uint32_t>(first + i + 1);
      y ^= v[static_cast<std::uint32_t>(__builtin_ctz(next | 0x80000000u))];
    }
  }
}

}  // namespace tally
