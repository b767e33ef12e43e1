#pragma once
// Rank-1 lattice rules {k z / n} built by the component-by-component (CBC)
// construction for product weights (Nuyens & Cools 2006, the fast O(s n log n) version):
// the generating vector z, one component at a time, minimises the worst-case error
// P_2 of the weighted Korobov space of smoothness alpha = 2,
//   P_2(z)^2 = -1 + (1/n) sum_{k<n} prod_j (1 + gamma_j omega({k z_j / n})),
//   omega(x) = 2 pi^2 (x^2 - x + 1/6)     (= sum_{h != 0} e^{2 pi i h x} / h^2),
// over z_j in 1..(n-1)/2 (z_j and n - z_j give the same error). n is prime: the
// units mod n form a cyclic group (a primitive root g), so the n - 1 candidate errors
// of one component are one circulant matrix-vector product, done by FFT.
#include <cmath>
#include <cstdint>
#include <memory>
#include <vector>

namespace tally {

struct LatticeRule {
  uint32_t n = 0;               // points (prime)
  std::vector<uint32_t> z;      // generating vector, one entry per dimension
  std::vector<double> weights;  // the product weights gamma_j CBC used
  double worst_case_error = 0;  // P_2(z) with those weights
};

// The largest prime <= n (n >= 2).
uint32_t largest_prime_at_most(uint32_t n);
bool is_prime(uint32_t n);
// The smallest primitive root modulo the prime n.
uint32_t primitive_root(uint32_t n);

// Fast CBC: O(s n log n) time, O(n) memory. n prime >= 3, weights.size() = s.
LatticeRule cbc_lattice_rule(uint32_t n, const std::vector<double>& weights);
// The plain CBC, O(s n^2): the reference the fast one is tested against.
LatticeRule cbc_lattice_rule_plain(uint32_t n, const std::vector<double>& weights);
// P_2(z) of any generating vector, computed directly in O(s n).
double lattice_worst_case_error(uint32_t n, const std::vector<uint32_t>& z, const std::vector<double>& weights);

// An embedded (extensible) rank-1 lattice in base 2: z odd, and for every m in
// [m_min, m_max] the first 2^m points in radical-inverse order, {phi_2(i) z} for
// i < 2^m, are the 2^m-point lattice {k (z mod 2^m) / 2^m}. Built by a fast CBC over
// n = 2^m_max (Cools, Kuo & Nuyens 2006): component s is the odd z minimising
//   max over m of P_2(2^m; z_1..z_s)^2 / (the smallest such error any odd z_s gives at 2^m),
// so no level is given up for another. The odd residues mod 2^q are +-5^e
// (e < 2^(q-2)); omega is even about 1/2, so the sign drops out and the candidates'
// errors, one 2-adic valuation of k at a time, are cyclic correlations of length 2^(q-2)
// (one FFT each): O(s n log n) time, O(n) memory.
struct EmbeddedLatticeRule {
  uint32_t m_min = 0, m_max = 0;
  std::vector<uint32_t> z;                // odd, < 2^m_max, one per dimension
  std::vector<double> weights;            // the product weights CBC used
  std::vector<double> worst_case_error;   // P_2 at n = 2^m, index m - m_min
};

// 3 <= m_min <= m_max <= kMaxEmbeddedLatticeLog2.
inline constexpr uint32_t kMaxEmbeddedLatticeLog2 = 24;
EmbeddedLatticeRule cbc_embedded_lattice_rule(uint32_t m_min, uint32_t m_max, const std::vector<double>& weights);
// The same criterion computed directly, O(s n^2 / 4): the reference the fast one is tested against.
EmbeddedLatticeRule cbc_embedded_lattice_rule_plain(uint32_t m_min, uint32_t m_max,
                                                    const std::vector<double>& weights);

// The embedded rule for (m_min, m_max, weights), built once and remembered (the last 8
// asked for, process-wide): a job spec's compile asks for it. Thread-safe; two threads
// asking for the same new rule at once may both build it.
std::shared_ptr<const EmbeddedLatticeRule> embedded_lattice_rule_remembered(uint32_t m_min, uint32_t m_max,
                                                                           const std::vector<double>& weights);

// The product weights CBC uses unless a spec gives some: gamma_j = 0.1 in every
// dimension (no dimension assumed more important than another, as in the Genz suite).
inline constexpr double kDefaultLatticeWeight = 0.1;
// The fast CBC construction runs when the spec compiles: O(s n log n) with FFTs of
// length ~n, 0.3 s of CPU for n = 65521 and s = 32 (LatticeRule.FastCbcTimeAtTheLargestSize).
inline constexpr uint32_t kMaxLatticePoints = uint32_t{1} << 16;

// Periodizing transforms of [0,1] applied per coordinate before the integrand, so a
// smooth non-periodic integrand becomes (nearly) periodic; `jacobian` multiplies the
// value. baker (tent) 1 - |2u - 1|: measure preserving, Jacobian 1 (Hickernell 2002);
// cubic (Korobov's polynomial transform of degree 3) u^2 (3 - 2u), Jacobian 6u(1 - u).
enum class Periodization { none, baker, cubic };

// u in [0, 1) through the transform; the cubic one multiplies *jacobian by its Jacobian.
inline double periodized(double u, Periodization per, double* jacobian) {
  if (per == Periodization::baker) return 1.0 - std::fabs(2.0 * u - 1.0);
  if (per == Periodization::cubic) {
    *jacobian *= 6.0 * u * (1.0 - u);
    return u * u * (3.0 - 2.0 * u);
  }
  return u;
}

}  // namespace tally
