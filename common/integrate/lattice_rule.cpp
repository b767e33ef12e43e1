#include "common/integrate/lattice_rule.hpp"

#include <cmath>
#include <numbers>
#include <stdexcept>

#include "common/integrate/cyclic_convolution.hpp"

namespace tally {

namespace {

// omega({m / n}) for m in 0..n-1: the Bernoulli-polynomial kernel of alpha = 2.
double omega(uint64_t m, uint32_t n) {
  const double x = static_cast<double>(m) / static_cast<double>(n);
  return 2.0 * std::numbers::pi * std::numbers::pi * (x * x - x + 1.0 / 6.0);
}

uint64_t pow_mod(uint64_t b, uint64_t e, uint64_t m) {
  uint64_t r = 1;
  b %= m;
  for (; e > 0; e >>= 1) {
    if (e & 1) r = r * b % m;
    b = b * b % m;
  }
  return r;
}

void check_arguments(uint32_t n, const std::vector<double>& weights) {
  if (n < 3 || !is_prime(n)) throw std::invalid_argument("CBC: n must be a prime >= 3");
  if (weights.empty()) throw std::invalid_argument("CBC: no dimensions");
  for (double g : weights) {
    if (!(g > 0.0) || !std::isfinite(g)) throw std::invalid_argument("CBC: weights must be positive");
  }
}

// Index of the smallest candidate error; near-ties (rounding of the FFT) go to the
// smaller z so the choice does not hinge on the last bits.
uint32_t pick(const std::vector<double>& err_of_z, uint32_t n) {
  uint32_t best = 1;
  for (uint32_t z = 2; z <= (n - 1) / 2; ++z) {
    const double tol = 1e-12 * std::fabs(err_of_z[best]) + 1e-300;
    if (err_of_z[z] < err_of_z[best] - tol) best = z;
  }
  return best;
}

void multiply_in(std::vector<double>& p, uint32_t n, uint32_t z, double gamma) {
  for (uint32_t k = 0; k < n; ++k) p[k] *= 1.0 + gamma * omega(static_cast<uint64_t>(k) * z % n, n);
}

}  // namespace

bool is_prime(uint32_t n) {
  if (n < 2) return false;
  if (n % 2 == 0) return n == 2;
  for (uint32_t d = 3; static_cast<uint64_t>(d) * d <= n; d += 2) {
    if (n % d == 0) return false;
  }
  return true;
}

uint32_t largest_prime_at_most(uint32_t n) {
  if (n < 2) throw std::invalid_argument("largest_prime_at_most: n < 2");
  while (!is_prime(n)) --n;
  return n;
}

uint32_t primitive_root(uint32_t n) {
  if (!is_prime(n)) throw std::invalid_argument("primitive_root: n is not prime");
  if (n == 2) return 1;
  std::vector<uint32_t> factors;
  uint32_t m = n - 1;
  for (uint32_t d = 2; static_cast<uint64_t>(d) * d <= m; ++d) {
    if (m % d == 0) {
      factors.push_back(d);
      while (m % d == 0) m /= d;
    }
  }
  if (m > 1) factors.push_back(m);
  for (uint32_t g = 2; g < n; ++g) {
    bool ok = true;
    for (uint32_t q : factors) ok = ok && pow_mod(g, (n - 1) / q, n) != 1;
    if (ok) return g;
  }
  throw std::logic_error("primitive_root: none found");
}

double lattice_worst_case_error(uint32_t n, const std::vector<uint32_t>& z, const std::vector<double>& weights) {
  if (z.size() != weights.size()) throw std::invalid_argument("lattice_worst_case_error: sizes differ");
  double sum = 0.0;
  for (uint32_t k = 0; k < n; ++k) {
    double prod = 1.0;
    for (size_t j = 0; j < z.size(); ++j) prod *= 1.0 + weights[j] * omega(static_cast<uint64_t>(k) * z[j] % n, n);
    sum += prod;
  }
  return std::sqrt(std::max(0.0, sum / n - 1.0));
}

namespace {

// The CBC loop: component s is the z minimising the error given components < s;
// `candidate_errors(p, err)` fills err[z] for z in 1..n-1 (up to terms that do not depend
// on z) from p(k) = prod_{j<s} (1 + gamma_j omega({k z_j / n})).
template <class CandidateErrors>
LatticeRule run_cbc(uint32_t n, const std::vector<double>& weights, CandidateErrors&& candidate_errors) {
  check_arguments(n, weights);
  LatticeRule rule;
  rule.n = n;
  rule.weights = weights;
  std::vector<double> p(n, 1.0), err(n, 0.0);
  for (size_t s = 0; s < weights.size(); ++s) {
    uint32_t zs = 1;  // the first component: every unit gives the same error
    if (s > 0) {
      candidate_errors(p, err);
      zs = pick(err, n);
    }
    rule.z.push_back(zs);
    multiply_in(p, n, zs, weights[s]);
  }
  double sum = 0.0;
  for (double pk : p) sum += pk;
  rule.worst_case_error = std::sqrt(std::max(0.0, sum / n - 1.0));
  return rule;
}

}  // namespace

LatticeRule cbc_lattice_rule(uint32_t n, const std::vector<double>& weights) {
  check_arguments(n, weights);
  const uint32_t L = n - 1;
  const uint32_t g = primitive_root(n);
  // g^m mod n for m = 0..L-1: the units in the group's cyclic order.
  std::vector<uint32_t> gm(L);
  uint64_t v = 1;
  for (uint32_t m = 0; m < L; ++m) {
    gm[m] = static_cast<uint32_t>(v);
    v = v * g % n;
  }
  // g^(L/2) = -1 mod n and omega(x) = omega(1 - x), so both c[m] = omega({g^m / n}) and
  // p(g^-j) have period L/2: the length-L circulant product is twice one of length L/2
  // (Nuyens & Cools' use of the symmetry; it halves the FFT length).
  const uint32_t H = L / 2;
  std::vector<double> c(H);
  for (uint32_t m = 0; m < H; ++m) c[m] = omega(gm[m], n);
  const CyclicConvolution conv(c);
  std::vector<double> x(H);
  return run_cbc(n, weights, [&](const std::vector<double>& p, std::vector<double>& err) {
    // y[i] = sum_j omega({g^(i-j) / n}) p(g^-j) = sum over units k of omega({k g^i / n}) p(k).
    for (uint32_t j = 0; j < H; ++j) x[j] = p[gm[(L - j) % L]];
    const std::vector<double> y = conv.apply(x);
    for (uint32_t i = 0; i < H; ++i) {
      err[gm[i]] = 2.0 * y[i];
      err[n - gm[i]] = 2.0 * y[i];
    }
  });
}

LatticeRule cbc_lattice_rule_plain(uint32_t n, const std::vector<double>& weights) {
  return run_cbc(n, weights, [n](const std::vector<double>& p, std::vector<double>& err) {
    for (uint32_t z = 1; z <= (n - 1) / 2; ++z) {
      double t = 0.0;  // over units k only, as the fast version (k = 0 adds the same to all)
      for (uint32_t k = 1; k < n; ++k) t += p[k] * omega(static_cast<uint64_t>(k) * z % n, n);
      err[z] = t;
    }
  });
}

}  // namespace tally
