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

}  // namespace tally
