// The component-by-component construction of rank-1 lattice rules
// (common/integrate/lattice_rule.hpp): the fast (FFT) CBC chooses exactly the vectors
// of the plain O(s n^2) CBC, the worst-case error it minimises falls with n and beats
// random generating vectors, and the circulant products it rests on are exact.
#include <gtest/gtest.h>

#include <ctime>
#include <cmath>
#include <limits>
#include <cstdio>
#include <numeric>
#include <random>

#include "common/integrate/cyclic_convolution.hpp"
#include "common/integrate/lattice_rule.hpp"

namespace tally {
namespace {

TEST(CyclicConvolution, MatchesTheDirectSum) {
  for (size_t L : {1u, 2u, 7u, 64u, 100u, 1020u, 1024u}) {  // padded and unpadded (powers of two)
    std::mt19937_64 g(L);
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    std::vector<double> c(L), x(L);
    for (size_t i = 0; i < L; ++i) {
      c[i] = u(g);
      x[i] = u(g);
    }
    const std::vector<double> y = CyclicConvolution(c).apply(x);
    for (size_t i = 0; i < L; ++i) {
      double direct = 0.0;
      for (size_t j = 0; j < L; ++j) direct += c[(i + L - j) % L] * x[j];
      EXPECT_NEAR(y[i], direct, 1e-12 * static_cast<double>(L)) << L << " " << i;
    }
  }
}

TEST(LatticeRule, PrimesAndPrimitiveRoots) {
  EXPECT_EQ(largest_prime_at_most(1024), 1021u);
  EXPECT_EQ(largest_prime_at_most(1021), 1021u);
  EXPECT_EQ(largest_prime_at_most(uint32_t{1} << 16), 65521u);
  EXPECT_FALSE(is_prime(1));
  EXPECT_FALSE(is_prime(561));  // a Carmichael number
  EXPECT_EQ(primitive_root(7), 3u);
  EXPECT_EQ(primitive_root(1021), 10u);  // 2, 3, 5, 6, 7, 8, 9 have smaller orders mod 1021
  // g generates the whole group: its powers visit every unit once.
  const uint32_t n = 1009, g = primitive_root(n);
  std::vector<bool> seen(n, false);
  uint64_t v = 1;
  for (uint32_t m = 0; m + 1 < n; ++m, v = v * g % n) {
    EXPECT_FALSE(seen[v]) << m;
    seen[v] = true;
  }
}

TEST(LatticeRule, FastCbcChoosesThePlainCbcVector) {
  // 17 and 257: (n - 1) / 2 is a power of two, the circulant's unpadded FFT.
  for (uint32_t n : {17u, 101u, 251u, 257u, 1009u}) {
    for (const std::vector<double>& w :
         {std::vector<double>(8, 0.1), std::vector<double>{1.0, 0.25, 1.0 / 9, 1.0 / 16, 0.04, 1.0 / 36, 1.0 / 49}}) {
      const LatticeRule fast = cbc_lattice_rule(n, w);
      const LatticeRule plain = cbc_lattice_rule_plain(n, w);
      EXPECT_EQ(fast.z, plain.z) << n;
      EXPECT_NEAR(fast.worst_case_error, plain.worst_case_error, 1e-12 * plain.worst_case_error);
      // The error CBC tracks incrementally is the error of the vector it returns.
      EXPECT_NEAR(fast.worst_case_error, lattice_worst_case_error(n, fast.z, w), 1e-12);
      for (uint32_t z : fast.z) {
        EXPECT_GE(z, 1u);
        EXPECT_LE(z, (n - 1) / 2);
      }
    }
  }
}

// P_2 of the CBC vector falls with n, close to the O(n^-1+delta) the theory promises for
// alpha = 2 (Kuo 2003), and is below every one of 100 random generating vectors.
TEST(LatticeRule, WorstCaseErrorFallsWithNAndBeatsRandomVectors) {
  const std::vector<uint32_t> ns = {127, 257, 509, 1021, 2039, 4093, 8191, 16381, 32749, 65521};
  for (size_t s : {8u, 16u}) {
    const std::vector<double> w(s, 0.1);
    std::vector<double> lx, ly;
    double prev = std::numeric_limits<double>::infinity();
    for (uint32_t n : ns) {
      const LatticeRule r = cbc_lattice_rule(n, w);
      EXPECT_LT(r.worst_case_error, prev) << "s = " << s << ", n = " << n;
      prev = r.worst_case_error;
      lx.push_back(std::log(n));
      ly.push_back(std::log(r.worst_case_error));
    }
    const double mx = std::accumulate(lx.begin(), lx.end(), 0.0) / lx.size();
    const double my = std::accumulate(ly.begin(), ly.end(), 0.0) / ly.size();
    double sxy = 0, sxx = 0;
    for (size_t i = 0; i < lx.size(); ++i) {
      sxy += (lx[i] - mx) * (ly[i] - my);
      sxx += (lx[i] - mx) * (lx[i] - mx);
    }
    const double slope = sxy / sxx;
    std::printf("s = %zu: P_2 slope over n = 127..65521: %.3f (n = 65521: %.3e)\n", s, slope, prev);
    // Theory: n^(-1 + delta) as n -> infinity; over this range, with the weights' sum
    // 0.8 (s = 8) and 1.6 (s = 16), the fit gives -0.68 and -0.55: the asymptotic rate has
    // not set in for s = 16. Random point sets' root-mean-square worst case falls as n^-0.5.
    EXPECT_LT(slope, s == 8 ? -0.6 : -0.5) << s;

    const uint32_t n = 1021;
    const double cbc = cbc_lattice_rule(n, w).worst_case_error;
    std::mt19937_64 g(7);
    std::uniform_int_distribution<uint32_t> pick(1, n - 1);
    double best_random = std::numeric_limits<double>::infinity();
    for (int t = 0; t < 100; ++t) {
      std::vector<uint32_t> z(s);
      for (auto& zj : z) zj = pick(g);
      best_random = std::min(best_random, lattice_worst_case_error(n, z, w));
    }
    std::printf("s = %zu, n = 1021: CBC %.4e, best of 100 random vectors %.4e\n", s, cbc, best_random);
    EXPECT_LT(cbc, best_random) << s;
  }
}

TEST(LatticeRule, FastCbcTimeAtTheLargestSize) {
  const uint32_t n = largest_prime_at_most(uint32_t{1} << 16);
  const std::clock_t t0 = std::clock();
  const LatticeRule r = cbc_lattice_rule(n, std::vector<double>(32, 0.1));
  const double secs = static_cast<double>(std::clock() - t0) / CLOCKS_PER_SEC;
  std::printf("fast CBC n = %u, s = 32: %.3f s of CPU, P_2 = %.3e\n", n, secs, r.worst_case_error);
  EXPECT_EQ(r.z.size(), 32u);
  EXPECT_GT(r.worst_case_error, 0.0);
}

// The embedded (2^m) construction: the fast one picks the plain one's vector, the
// errors it reports are the errors of z mod 2^m at every level, and every z is odd.
TEST(EmbeddedLatticeRule, FastCbcChoosesThePlainCbcVector) {
  for (auto [m_min, m_max] : {std::pair<uint32_t, uint32_t>{3, 7}, {4, 9}, {9, 9}}) {
    for (const std::vector<double>& w :
         {std::vector<double>(6, 0.1), std::vector<double>{1.0, 0.25, 1.0 / 9, 1.0 / 16, 0.04, 1.0 / 36, 1.0 / 49}}) {
      const EmbeddedLatticeRule fast = cbc_embedded_lattice_rule(m_min, m_max, w);
      const EmbeddedLatticeRule plain = cbc_embedded_lattice_rule_plain(m_min, m_max, w);
      EXPECT_EQ(fast.z, plain.z) << m_min << ".." << m_max;
      ASSERT_EQ(fast.worst_case_error.size(), m_max - m_min + 1);
      for (uint32_t m = m_min; m <= m_max; ++m) {
        std::vector<uint32_t> zm;
        for (uint32_t z : fast.z) zm.push_back(z & ((uint32_t{1} << m) - 1));
        EXPECT_NEAR(fast.worst_case_error[m - m_min], lattice_worst_case_error(uint32_t{1} << m, zm, w),
                    1e-12) << m;
      }
      for (uint32_t z : fast.z) {
        EXPECT_EQ(z % 2, 1u);
        EXPECT_LT(z, uint32_t{1} << m_max);
      }
    }
  }
}

// Good at every level: at each 2^m, m = 10..16, the embedded rule's P_2 is close to the
// CBC rule built for that size alone (the prime just below 2^m) and below the best of
// 30 random odd vectors.
TEST(EmbeddedLatticeRule, GoodAtEveryLevel) {
  const std::vector<double> w(12, 0.1);
  const EmbeddedLatticeRule e = cbc_embedded_lattice_rule(10, 16, w);
  std::mt19937_64 g(11);
  for (uint32_t m = 10; m <= 16; ++m) {
    const uint32_t n = uint32_t{1} << m;
    const double alone = cbc_lattice_rule(largest_prime_at_most(n), w).worst_case_error;
    double best_random = std::numeric_limits<double>::infinity();
    std::uniform_int_distribution<uint32_t> pick(0, n / 2 - 1);
    for (int t = 0; t < 30; ++t) {
      std::vector<uint32_t> z(w.size());
      for (auto& zj : z) zj = 2 * pick(g) + 1;
      best_random = std::min(best_random, lattice_worst_case_error(n, z, w));
    }
    const double emb = e.worst_case_error[m - 10];
    std::printf("2^%u: embedded P_2 %.4e, CBC for this n alone %.4e (ratio %.3f), best random %.4e\n", m, emb,
                alone, emb / alone, best_random);
    EXPECT_LT(emb, 1.3 * alone) << m;
    EXPECT_LT(emb, best_random) << m;
  }
}

// The size the lattice cone rule builds (2^20; the time is printed, not asserted:
// docs/jobs.md quotes it for d = 8 and 32).
TEST(EmbeddedLatticeRule, TimeAtTheConeRulesSize) {
  const std::clock_t t0 = std::clock();
  const EmbeddedLatticeRule r = cbc_embedded_lattice_rule(10, 20, std::vector<double>(8, 0.1));
  const double secs = static_cast<double>(std::clock() - t0) / CLOCKS_PER_SEC;
  std::printf("embedded CBC 2^10..2^20, s = 8: %.3f s of CPU, P_2 at 2^20 = %.3e\n", secs, r.worst_case_error.back());
  EXPECT_EQ(r.z.size(), 8u);
  // P_2 falls at every doubling.
  for (size_t l = 1; l < r.worst_case_error.size(); ++l) EXPECT_LT(r.worst_case_error[l], r.worst_case_error[l - 1]);
}

TEST(LatticeRule, BadArgumentsThrow) {
  EXPECT_THROW(cbc_embedded_lattice_rule(2, 8, {0.1}), std::invalid_argument);
  EXPECT_THROW(cbc_embedded_lattice_rule(9, 8, {0.1}), std::invalid_argument);
  EXPECT_THROW(cbc_embedded_lattice_rule(10, 25, {0.1}), std::invalid_argument);
  EXPECT_THROW(cbc_embedded_lattice_rule(4, 8, {0.1, 0.0}), std::invalid_argument);
  EXPECT_THROW(cbc_lattice_rule(1024, {0.1}), std::invalid_argument);
  EXPECT_THROW(cbc_lattice_rule(101, {}), std::invalid_argument);
  EXPECT_THROW(cbc_lattice_rule(101, {0.1, -1.0}), std::invalid_argument);
}

}  // namespace
}  // namespace tally
