// Higher-order digital nets by interlacing (InterlacedSobolSet, common/sampling/qmc.hpp):
// the digits are those of the underlying scrambled Sobol' set taken in turn, the first
// 2^m points keep the net's stratification at order alpha, and each coordinate is
// uniform over scrambles.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdint>
#include <stdexcept>
#include <vector>

#include "common/sampling/qmc.hpp"

namespace tally {
namespace {

// Bit by bit: digit k (from the most significant) of the result is digit k / alpha of
// word k % alpha; 52 digits.
std::uint64_t interlace_by_hand(const std::uint32_t* words, std::uint32_t alpha) {
  std::uint64_t out = 0;
  for (std::uint32_t k = 0; k < 52; ++k) {
    const std::uint32_t word = words[k % alpha], digit = k / alpha;  // digit 0 = bit 31
    const std::uint64_t bit = digit < 32 ? (word >> (31 - digit)) & 1u : 0u;
    out = (out << 1) | bit;
  }
  return out;
}

TEST(InterlacedSobol, DigitsAreTheUnderlyingSetsTakenInTurn) {
  std::array<std::uint32_t, 3> w{};
  // Patterns that catch a wrong spread mask: single bits, alternating, all ones, random.
  const std::uint32_t patterns[] = {0u, 1u, 0x80000000u, 0xFFFFFFFFu, 0xAAAAAAAAu, 0x55555555u, 0x12345678u,
                                    0xDEADBEEFu, 0x00100000u, 0x00000800u, 0x001FFFFFu};
  for (std::uint32_t alpha : {2u, 3u}) {
    for (std::uint32_t a : patterns) {
      for (std::uint32_t b : patterns) {
        for (std::uint32_t c : patterns) {
          w = {a, b, c};
          ASSERT_EQ(interlace_digits(w.data(), alpha), interlace_by_hand(w.data(), alpha))
              << alpha << " " << a << " " << b << " " << c;
        }
      }
    }
  }
  // The points: coordinate j of point i from dimensions alpha j .. alpha j + alpha - 1 of
  // the same scrambled set (same seed), at the midpoint of its 2^-52 cell.
  constexpr std::uint32_t kDims = 5, kN = 300, kFirst = 77;
  for (std::uint32_t alpha : {2u, 3u}) {
    const InterlacedSobolSet hi(0x5eed, kDims, alpha);
    const ScrambledSobolSet base(0x5eed, kDims * alpha);
    std::vector<std::vector<double>> rows(kDims, std::vector<double>(kN));
    std::vector<double*> ptrs;
    for (auto& r : rows) ptrs.push_back(r.data());
    hi.fill(kFirst, kN, ptrs.data());
    std::vector<std::vector<std::uint32_t>> bits(kDims * alpha, std::vector<std::uint32_t>(kN));
    for (std::uint32_t d = 0; d < kDims * alpha; ++d) base.fill_bits(d, kFirst, kN, bits[d].data());
    for (std::uint32_t j = 0; j < kDims; ++j) {
      for (std::uint32_t i = 0; i < kN; ++i) {
        std::array<std::uint32_t, 3> words{};
        for (std::uint32_t a = 0; a < alpha; ++a) words[a] = bits[j * alpha + a][i];
        const double want = (static_cast<double>(interlace_by_hand(words.data(), alpha)) + 0.5) * 0x1.0p-52;
        ASSERT_EQ(rows[j][i], want) << alpha << " " << j << " " << i;
        ASSERT_GT(rows[j][i], 0.0);
        ASSERT_LT(rows[j][i], 1.0);
      }
    }
    // fill's coordinates are fill_bits' plus the set's draw below them (a dimension's
    // scramble depends on the seed and the dimension alone).
    std::vector<double> row(kN);
    double* rp = row.data();
    ScrambledSobolSet(0x5eed, 1).fill(kFirst, kN, &rp);
    for (std::uint32_t i = 0; i < kN; ++i) {
      EXPECT_EQ(std::floor(row[i] * 0x1.0p32), static_cast<double>(bits[0][i])) << i;
    }
  }
  EXPECT_THROW(InterlacedSobolSet(1, 2, 4), std::invalid_argument);
  EXPECT_THROW(InterlacedSobolSet(1, 600, 2), std::out_of_range);
}

// The order-2 property in one dimension: the first 2^m points of one coordinate come
// from a 2-dimensional (0, m, 2)-net (Sobol' dimensions 0 and 1, scrambled), so every
// elementary interval [a 2^-k1, (a+1) 2^-k1) x [b 2^-k2, ...) with k1 + k2 = m holds one
// point; interlaced, the first m digits of the coordinate (k1 = ceil(m/2) digits of the
// first, k2 = floor(m/2) of the second) are distinct across the 2^m points: one point
// in each interval of length 2^-m.
TEST(InterlacedSobol, TheFirstTwoToTheMPointsStratifyEachCoordinate) {
  for (std::uint32_t m : {4u, 8u, 12u}) {
    const std::size_t n = std::size_t{1} << m;
    const InterlacedSobolSet hi(0xC0FFEE + m, 1, 2);
    std::vector<double> row(n);
    double* rp = row.data();
    hi.fill(0, n, &rp);
    std::vector<int> hits(n, 0);
    for (double u : row) ++hits[static_cast<std::size_t>(u * static_cast<double>(n))];
    for (std::size_t c = 0; c < n; ++c) ASSERT_EQ(hits[c], 1) << "m " << m << " cell " << c;
  }
}

// Each coordinate is uniform over scrambles: the mean of u (1/2) and of u^2 (1/3) over
// 4000 independent scrambles of one point, within 4 standard errors (sd of u 0.289,
// of u^2 0.298).
TEST(InterlacedSobol, ACoordinateIsUniformOverScrambles) {
  constexpr int kScrambles = 4000;
  for (std::uint32_t alpha : {2u, 3u}) {
    double s1 = 0, s2 = 0;
    for (int k = 0; k < kScrambles; ++k) {
      const InterlacedSobolSet hi(0xABCD0000u + static_cast<std::uint64_t>(k), 2, alpha);
      std::array<double, 1> a{}, b{};
      std::array<double*, 2> rows{a.data(), b.data()};
      hi.fill(5, 1, rows.data());
      s1 += b[0];
      s2 += b[0] * b[0];
    }
    const double se = 1.0 / std::sqrt(static_cast<double>(kScrambles));
    EXPECT_NEAR(s1 / kScrambles, 0.5, 4 * 0.289 * se) << alpha;
    EXPECT_NEAR(s2 / kScrambles, 1.0 / 3.0, 4 * 0.298 * se) << alpha;
  }
}

}  // namespace
}  // namespace tally
