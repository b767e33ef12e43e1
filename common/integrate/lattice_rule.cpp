#include "common/integrate/lattice_rule.hpp"

#include <algorithm>
#include <cmath>
#include <deque>
#include <mutex>
#include <limits>
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

namespace tally {

namespace {

void check_embedded(uint32_t m_min, uint32_t m_max, const std::vector<double>& weights) {
  if (!(3 <= m_min && m_min <= m_max && m_max <= kMaxEmbeddedLatticeLog2)) {
    throw std::invalid_argument("embedded CBC: needs 3 <= m_min <= m_max <= 24");
  }
  if (weights.empty()) throw std::invalid_argument("embedded CBC: no dimensions");
  for (double g : weights) {
    if (!(g > 0.0) || !std::isfinite(g)) throw std::invalid_argument("embedded CBC: weights must be positive");
  }
}

// The CBC loop of an embedded rule. The candidates for a component are z = 5^a mod 2^M,
// a < 2^(M-2) (with their negatives, every odd residue; z and -z give the same errors).
// `valuation_sums(p, C)` fills, for each 2-adic valuation v < M, C[v][a mod C[v].size()]
// = sum over k = 2^v k' (k' odd) of p(k) omega({k z / 2^M}), z = 5^a (C[v].size() a power
// of two dividing 2^(M-2): the sum depends on z mod 2^(M-v) only).
template <class ValuationSums>
EmbeddedLatticeRule run_embedded_cbc(uint32_t m_min, uint32_t M, const std::vector<double>& weights,
                                     const std::vector<uint32_t>& pow5, ValuationSums&& valuation_sums) {
  const uint64_t n = uint64_t{1} << M;
  const uint32_t levels = M - m_min + 1;
  const size_t A = pow5.size();
  EmbeddedLatticeRule rule;
  rule.m_min = m_min;
  rule.m_max = M;
  rule.weights = weights;
  std::vector<double> p(n, 1.0);
  std::vector<std::vector<double>> C(M);
  std::vector<double> base(levels), best(levels), e(levels), inv_n(levels);
  for (uint32_t l = 0; l < levels; ++l) inv_n[l] = std::ldexp(1.0, -static_cast<int>(m_min + l));
  // The sum of p over the 2^m-point sub-lattice (k a multiple of 2^(M - m)).
  auto sublattice_sum = [&](uint32_t m) {
    double t = 0.0;
    for (uint64_t k = 0; k < n; k += n >> m) t += p[k];
    return t;
  };
  for (size_t s = 0; s < weights.size(); ++s) {
    uint32_t zs = 1;  // the first component: every odd z permutes the same points
    if (s > 0) {
      valuation_sums(p, C);
      const double g = weights[s];
      const double k0 = p[0] * omega(0, static_cast<uint32_t>(n));
      // errors(a): e[l] = P_2(2^(m_min + l))^2 with z_s = 5^a; the 2^m-point sub-lattice
      // holds k = 0 and the valuations v >= M - m.
      auto errors = [&](size_t a) {
        double t = k0;
        for (uint32_t v = M - 1; v > M - m_min; --v) t += C[v][a & (C[v].size() - 1)];
        for (uint32_t l = 0; l < levels; ++l) {
          const uint32_t v = M - m_min - l;
          t += C[v][a & (C[v].size() - 1)];
          e[l] = (base[l] + g * t) * inv_n[l] - 1.0;
        }
      };
      for (uint32_t l = 0; l < levels; ++l) {
        base[l] = sublattice_sum(m_min + l);
        best[l] = std::numeric_limits<double>::infinity();
      }
      for (size_t a = 0; a < A; ++a) {
        errors(a);
        for (uint32_t l = 0; l < levels; ++l) best[l] = std::min(best[l], e[l]);
      }
      size_t chosen = 0;
      double chosen_score = std::numeric_limits<double>::infinity();
      for (size_t a = 0; a < A; ++a) {
        errors(a);
        double score = 0.0;
        for (uint32_t l = 0; l < levels; ++l) score = std::max(score, e[l] / std::max(best[l], 1e-300));
        // Near-ties (rounding) go to the smaller a, so the choice does not hinge on the last bits.
        if (score < chosen_score * (1.0 - 1e-9)) {
          chosen_score = score;
          chosen = a;
        }
      }
      zs = pow5[chosen];
    }
    rule.z.push_back(zs);
    for (uint64_t k = 0; k < n; ++k) p[k] *= 1.0 + weights[s] * omega(k * zs & (n - 1), static_cast<uint32_t>(n));
  }
  for (uint32_t l = 0; l < levels; ++l) {
    rule.worst_case_error.push_back(
        std::sqrt(std::max(0.0, std::ldexp(sublattice_sum(m_min + l), -static_cast<int>(m_min + l)) - 1.0)));
  }
  return rule;
}

// 5^a mod 2^M for a < 2^(M-2): the odd residues up to sign.
std::vector<uint32_t> powers_of_five(uint32_t M) {
  const uint64_t mask = (uint64_t{1} << M) - 1;
  std::vector<uint32_t> pow5(size_t{1} << (M - 2));
  uint64_t v = 1;
  for (auto& x : pow5) {
    x = static_cast<uint32_t>(v);
    v = v * 5 & mask;
  }
  return pow5;
}

}  // namespace

EmbeddedLatticeRule cbc_embedded_lattice_rule(uint32_t m_min, uint32_t m_max, const std::vector<double>& weights) {
  check_embedded(m_min, m_max, weights);
  const uint32_t M = m_max;
  const std::vector<uint32_t> pow5 = powers_of_five(M);
  // For k = 2^v k' (k' odd, q = M - v), {k z / n} = {k' z / 2^q}. With q >= 3, k' = +-5^b
  // and z = 5^a mod 2^q, so omega({k z / n}) = omega({5^((a + b) mod 2^(q-2)) / 2^q}):
  // the sum over that valuation is the cyclic correlation
  //   C_v(a) = sum_b P_v(b) c_q(a + b),  P_v(b) = p(2^v 5^b) + p(2^v (2^q - 5^b)) (mod 2^q),
  // c_q(e) = omega({5^e / 2^q}). q = 1, 2: one or two k', the same omega for every odd z.
  std::vector<CyclicConvolution> conv;  // index q - 3
  for (uint32_t q = 3; q <= M; ++q) {
    const size_t L = size_t{1} << (q - 2);
    const uint64_t qmask = (uint64_t{1} << q) - 1;
    std::vector<double> c(L);
    for (size_t e = 0; e < L; ++e) c[e] = omega(pow5[e] & qmask, static_cast<uint32_t>(uint64_t{1} << q));
    conv.emplace_back(c);
  }
  std::vector<double> x;
  return run_embedded_cbc(m_min, M, weights, pow5, [&](const std::vector<double>& p, auto& C) {
    for (uint32_t v = 0; v < M; ++v) {
      const uint32_t q = M - v;
      const uint64_t qn = uint64_t{1} << q, qmask = qn - 1;
      if (q <= 2) {
        double t = 0.0;
        for (uint64_t kp = 1; kp < qn; kp += 2) t += p[kp << v] * omega(kp, static_cast<uint32_t>(qn));
        C[v].assign(1, t);
        continue;
      }
      const size_t L = size_t{1} << (q - 2);
      x.resize(L);
      // apply() gives y[a] = sum_j c[a - j] x[j]: x[j] = P_v(-j) makes it sum_b c[a + b] P_v(b).
      for (size_t j = 0; j < L; ++j) {
        const uint64_t r = pow5[(L - j) % L] & qmask;
        x[j] = p[r << v] + p[(qn - r) << v];
      }
      C[v] = conv[q - 3].apply(x);
    }
  });
}

EmbeddedLatticeRule cbc_embedded_lattice_rule_plain(uint32_t m_min, uint32_t m_max,
                                                    const std::vector<double>& weights) {
  check_embedded(m_min, m_max, weights);
  const uint32_t M = m_max;
  const uint64_t n = uint64_t{1} << M;
  const std::vector<uint32_t> pow5 = powers_of_five(M);
  return run_embedded_cbc(m_min, M, weights, pow5, [&](const std::vector<double>& p, auto& C) {
    for (uint32_t v = 0; v < M; ++v) {
      C[v].assign(pow5.size(), 0.0);
      for (size_t a = 0; a < pow5.size(); ++a) {
        for (uint64_t k = uint64_t{1} << v; k < n; k += uint64_t{2} << v) {  // valuation exactly v
          C[v][a] += p[k] * omega(k * pow5[a] % n, static_cast<uint32_t>(n));
        }
      }
    }
  });
}

std::shared_ptr<const EmbeddedLatticeRule> embedded_lattice_rule_remembered(uint32_t m_min, uint32_t m_max,
                                                                           const std::vector<double>& weights) {
  struct Entry {
    uint32_t m_min, m_max;
    std::vector<double> weights;
    std::shared_ptr<const EmbeddedLatticeRule> rule;
  };
  static std::mutex mu;
  static std::deque<Entry> remembered;  // most recently used first
  {
    const std::lock_guard lock(mu);
    for (auto it = remembered.begin(); it != remembered.end(); ++it) {
      if (it->m_min == m_min && it->m_max == m_max && it->weights == weights) {
        Entry e = std::move(*it);
        remembered.erase(it);
        remembered.push_front(std::move(e));
        return remembered.front().rule;
      }
    }
  }
  auto rule = std::make_shared<const EmbeddedLatticeRule>(cbc_embedded_lattice_rule(m_min, m_max, weights));
  const std::lock_guard lock(mu);
  remembered.push_front({m_min, m_max, weights, rule});
  if (remembered.size() > 8) remembered.pop_back();
  return rule;
}

}  // namespace tally
