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
#include <cstdint>
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

}  // namespace tally
