#include "common/integrate/cone_rule.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <complex>
#include <numbers>
#include <type_traits>
#include <fmt/format.h>
#include <stdexcept>
#include <vector>

#include "common/engine/block_abandon.hpp"
#include "common/engine/job_state.hpp"
#include "common/integrate/integration_counters.hpp"
#include "common/integrate/rule_kernel.hpp"
#include "common/rng/counter_rng.hpp"
#include "common/sampling/qmc.hpp"
#include "common/sampling/sobol_burley.hpp"

namespace tally {

void walsh_hadamard_normalized(std::span<double> y) {
  const size_t n = y.size();
  if (n == 0 || (n & (n - 1)) != 0) throw std::invalid_argument("walsh_hadamard_normalized: size not a power of 2");
  for (size_t h = 1; h < n; h *= 2) {
    for (size_t b = 0; b < n; b += 2 * h) {
      for (size_t i = b; i < b + h; ++i) {
        // Halved first: the same bits as 0.5 * (a + c) (halving is exact above the
        // subnormals), but values near the largest double do not overflow.
        const double a = 0.5 * y[i], c = 0.5 * y[i + h];
        y[i] = a + c;
        y[i + h] = a - c;
      }
    }
  }
}

namespace {

// exp(-i pi j / h) for j < h: the twiddles of the level of span h.
std::vector<std::complex<double>> level_twiddles(size_t h) {
  std::vector<std::complex<double>> w(h);
  for (size_t j = 0; j < h; ++j) {
    w[j] = std::polar(1.0, -std::numbers::pi * static_cast<double>(j) / static_cast<double>(h));
  }
  return w;
}

void dft_level(std::span<std::complex<double>> y, size_t h, const std::vector<std::complex<double>>& w) {
  const size_t n = y.size();
  for (size_t b = 0; b < n; b += 2 * h) {
    for (size_t j = 0; j < h; ++j) {
      const std::complex<double> a = 0.5 * y[b + j], t = y[b + j + h];
      // (0.5 w) t written out: std::complex's operator* recovers NaN products by a libgcc call.
      const std::complex<double> c = {0.5 * (w[j].real() * t.real() - w[j].imag() * t.imag()),
                                      0.5 * (w[j].real() * t.imag() + w[j].imag() * t.real())};
      y[b + j] = a + c;
      y[b + j + h] = a - c;
    }
  }
}

}  // namespace

void lattice_dft_level(std::span<std::complex<double>> y, size_t h) {
  if (h == 0 || (h & (h - 1)) != 0 || y.size() % (2 * h) != 0) {
    throw std::invalid_argument("lattice_dft_level: bad span");
  }
  dft_level(y, h, level_twiddles(h));
}

void lattice_dft_normalized(std::span<std::complex<double>> y) {
  const size_t n = y.size();
  if (n == 0 || (n & (n - 1)) != 0) throw std::invalid_argument("lattice_dft_normalized: size not a power of 2");
  for (size_t h = 1; h < n; h *= 2) lattice_dft_level(y, h);
}

namespace {

// The coefficient order kappa, refined at level l (cubSobol_g): among the first 2^(l+1)
// positions, where the coefficient at position 2^l + j (0 < j < 2^l) is larger than the
// one at position j, the two swap, and so do the same pairs in every later block of
// 2^(l+1) positions. The pairs to swap are all found before any is swapped.
// |c| and a quantity in the same order (|c|^2 for complex c: no hypot, which is slow; a
// magnitude beyond 1e154 overflows to inf, and a bound of inf reads as not met).
inline double magnitude(double c) { return std::fabs(c); }
inline double magnitude(std::complex<double> c) { return std::sqrt(c.real() * c.real() + c.imag() * c.imag()); }
inline double order_key(double c) { return std::fabs(c); }
inline double order_key(std::complex<double> c) { return c.real() * c.real() + c.imag() * c.imag(); }

template <class T>
void refine_order(std::vector<uint32_t>& kappa, const std::vector<T>& y, uint32_t l, size_t n) {
  const size_t nl = size_t{1} << l;
  std::vector<size_t> flip;
  for (size_t j = 1; j < nl; ++j) {
    if (order_key(y[kappa[nl + j]]) > order_key(y[kappa[j]])) flip.push_back(j);
  }
  for (size_t b = 0; b < n; b += 2 * nl) {
    for (size_t j : flip) std::swap(kappa[b + j], kappa[b + nl + j]);
  }
}

// Sum of |coefficient| at kappa positions [2^(l-1), 2^l), l >= 1.
template <class T>
double band_sum(const std::vector<uint32_t>& kappa, const std::vector<T>& y, uint32_t l) {
  double s = 0.0;
  for (size_t i = size_t{1} << (l - 1); i < (size_t{1} << l); ++i) s += magnitude(y[kappa[i]]);
  return s;
}

// The transforms of the two bases: every level of a block of values, and the top level
// that joins two halves (each already transformed) into one.
struct WalshBasis {
  using T = double;
  void all(std::span<double> y) { walsh_hadamard_normalized(y); }
  void top(std::span<double> y) {
    const size_t h = y.size() / 2;
    for (size_t i = 0; i < h; ++i) {  // as in walsh_hadamard_normalized
      const double a = 0.5 * y[i], c = 0.5 * y[i + h];
      y[i] = a + c;
      y[i + h] = a - c;
    }
  }
};

class FourierBasis {
 public:
  using T = std::complex<double>;
  void all(std::span<T> y) {
    for (size_t h = 1; h < y.size(); h *= 2) dft_level(y, h, twiddles(h));
  }
  void top(std::span<T> y) { dft_level(y, y.size() / 2, twiddles(y.size() / 2)); }

 private:
  // Each level's twiddles, computed once a run.
  const std::vector<T>& twiddles(size_t h) {
    const auto l = static_cast<size_t>(std::countr_zero(h));
    if (w_.size() <= l) w_.resize(l + 1);
    if (w_[l].empty()) w_[l] = level_twiddles(h);
    return w_[l];
  }
  std::vector<std::vector<T>> w_;
};

// Asks for the values at positions [first, first + n) into y[first..] (in the basis' type).
template <class T>
bool fetch(const ConeValues& values, std::vector<T>& y, std::vector<double>& buf, uint64_t first, uint64_t n) {
  if constexpr (std::is_same_v<T, double>) {
    return values(first, n, y.data() + first);
  } else {
    buf.resize(n);
    if (!values(first, n, buf.data())) return false;
    for (uint64_t i = 0; i < n; ++i) y[first + i] = buf[i];
    return true;
  }
}

template <class Basis>
ConeRuleResult run_cone(const ConeRuleOptions& o, const ConeValues& values) {
  using T = typename Basis::T;
  if (!(o.lag + 1 <= o.m_min && o.m_min <= o.m_max && o.m_max <= 30) || !(o.fudge > 0.0)) {
    throw std::invalid_argument("run_cone_rule: needs lag + 1 <= m_min <= m_max <= 30 and fudge > 0");
  }
  ConeRuleResult r;
  Basis basis;
  std::vector<T> y(size_t{1} << o.m_min);
  std::vector<double> buf;
  std::vector<uint32_t> kappa(y.size());
  if (!fetch(values, y, buf, 0, y.size())) {
    r.aborted = true;
    return r;
  }
  basis.all(y);
  for (size_t i = 0; i < kappa.size(); ++i) kappa[i] = static_cast<uint32_t>(i);
  for (uint32_t l = o.m_min - 1; l >= 1; --l) refine_order(kappa, y, l, y.size());

  for (uint32_t m = o.m_min;; ++m) {
    const size_t n = size_t{1} << m;
    if (m > o.m_min) {  // double: the new half's values, their transform, one more level
      const size_t h = n / 2;
      y.resize(n);
      if (!fetch(values, y, buf, h, h)) {
        r.aborted = true;
        return r;
      }
      basis.all(std::span<T>(y).subspan(h, h));
      basis.top(y);
      kappa.resize(n);
      for (size_t i = 0; i < h; ++i) kappa[h + i] = kappa[i] + static_cast<uint32_t>(h);
      for (uint32_t l = m - 1; l >= m - o.lag; --l) refine_order(kappa, y, l, n);
    }
    const double S = band_sum(kappa, y, m - o.lag);
    r.m = m;
    r.mean = std::real(y[0]);
    r.error_bound = o.fudge * std::ldexp(S, -static_cast<int>(m));
    // Met when the bound is within the target for every value the bound allows: the
    // relative target is taken against the smallest |I| consistent with it.
    const double tol = std::max(o.abs_error, o.rel_error * (std::fabs(r.mean) - r.error_bound));
    r.met = (o.abs_error > 0.0 || o.rel_error > 0.0) && r.error_bound <= tol;
    if (r.met || m == o.m_max) return r;
  }
}

}  // namespace

ConeRuleResult run_cone_rule(const ConeRuleOptions& o, const ConeValues& values) {
  return o.basis == ConeBasis::walsh ? run_cone<WalshBasis>(o, values) : run_cone<FourierBasis>(o, values);
}

namespace {

constexpr size_t kB = kIntegrandBatch;

// The cone rule as a job's kernel: one block of one pass runs the whole rule (like
// cubature: the coefficients live in memory for the rule's length, not checkpointed;
// the block polls block_abandoned() between batches, so cancel stays prompt). Channels:
// 0 the mean, 1 the error bound. Subclasses give the points.
class ConeKernelBase : public RuleKernelBase {
 public:
  ConeKernelBase(IntegrationProblem p, ConeRuleOptions o) : RuleKernelBase(1), p_(std::move(p)), o_(o) {
    if (p_.integrand->components() != 1) throw std::invalid_argument("the cone rule takes a scalar integrand");
  }

 protected:
  // The uniforms of positions [p0, p0 + c) into urow[k][i]; jac[i] (set to 1 by the
  // caller) takes a periodizing transform's Jacobian.
  virtual void fill_uniforms(uint64_t p0, size_t c, double* const* urow, double* jac) const = 0;
  // Where the value of position p goes in the rule's order.
  virtual uint64_t slot(uint64_t p) const = 0;
  virtual const char* point_set() const = 0;

  void run_rule(BlockResult& out) const override {
    const Domain& D = *p_.domain;
    const uint32_t U = D.uniforms();
    const size_t dims = D.dimensions();
    std::vector<double> u(U * kB), x(dims * kB), f(kB), jac(kB);
    std::vector<double*> urow(U), xrow(dims);
    std::vector<const double*> ucrow(U), xcrow(dims);
    for (uint32_t k = 0; k < U; ++k) ucrow[k] = urow[k] = u.data() + k * kB;
    for (size_t k = 0; k < dims; ++k) xcrow[k] = xrow[k] = x.data() + k * kB;
    const double measure = D.measure();
    auto values = [&](uint64_t first, uint64_t n, double* dst) {
      for (uint64_t p0 = first; p0 < first + n; p0 += kB) {
        if (block_abandoned()) return false;
        const size_t c = static_cast<size_t>(std::min<uint64_t>(kB, first + n - p0));
        std::fill(jac.begin(), jac.begin() + static_cast<std::ptrdiff_t>(c), 1.0);
        fill_uniforms(p0, c, urow.data(), jac.data());
        for (uint32_t k = 0; k < U; ++k) {
          for (size_t i = 0; i < c; ++i) urow[k][i] = std::clamp(urow[k][i], 0x1.0p-54, 1.0 - 0x1.0p-53);
        }
        D.map_uniform(ucrow.data(), c, xrow.data());
        p_.integrand->evaluate_batch(xcrow.data(), c, f.data());
        out.counters.add(IntegrationCounter::evaluations, c);
        for (size_t i = 0; i < c; ++i) {
          if (!std::isfinite(f[i])) {
            out.counters.add(IntegrationCounter::nonfinite);
            SampleFault fault;
            fault.sample_index = 0;
            fault.value = f[i];
            std::string where;
            for (size_t k = 0; k < dims; ++k) {
              fault.point.push_back(xrow[k][i]);
              where += fmt::format("{}x{} = {:.17g}", k ? ", " : "", k, xrow[k][i]);
            }
            fault.message = fmt::format("the integrand is {} at {} (point {} of the cone rule's {})",
                                        std::isnan(f[i]) ? "NaN" : "infinite", where, p0 + i, point_set());
            out.fault = std::move(fault);
            return false;
          }
          dst[slot(p0 + i) - first] = measure * f[i] * jac[i];
        }
      }
      return true;
    };
    const ConeRuleResult r = run_cone_rule(o_, values);
    if (r.aborted) return;  // a fault (out.fault says where) or an abandoned block (dropped)
    out.tallies[0].add(r.mean);
    out.tallies[1].add(r.error_bound);
  }

  IntegrationProblem p_;
  ConeRuleOptions o_;
};

// One randomization of the Sobol' sequence, seeded as the qmc estimator's first point set.
class ConeKernel final : public ConeKernelBase {
 public:
  ConeKernel(IntegrationProblem p, ConeRuleOptions o)
      : ConeKernelBase(std::move(p), o),
        set_(mix64(stream_key(p_.seed, 0) ^ mix64(0 + 0x51ed27)), p_.domain->uniforms()) {}

 protected:
  void fill_uniforms(uint64_t p0, size_t c, double* const* urow, double*) const override {
    set_.fill(static_cast<uint32_t>(p0), c, urow);
  }
  // The set fills positions in Gray-code order, and positions [first, first + n) of a
  // doubling are the same natural indices (index = position ^ (position >> 1)).
  uint64_t slot(uint64_t p) const override { return p ^ (p >> 1); }
  const char* point_set() const override { return "Sobol' set"; }

 private:
  ScrambledSobolSet set_;
};

// The embedded lattice with the lattice estimator's first shift: position p is the point
// {phi_2(p) z + shift}, phi_2(p) = bitreverse_32(p) / 2^32 (exact: the product's low 32 bits).
class LatticeConeKernel final : public ConeKernelBase {
 public:
  LatticeConeKernel(IntegrationProblem p, EmbeddedLatticeRule rule, Periodization per, ConeRuleOptions o)
      : ConeKernelBase(std::move(p), o), rule_(std::move(rule)), per_(per) {
    if (o_.basis != ConeBasis::fourier || o_.m_max > rule_.m_max || rule_.z.size() != p_.domain->uniforms()) {
      throw std::invalid_argument("the lattice cone rule needs the Fourier basis and a rule of its size");
    }
    const SampleRng shift(stream_key(p_.seed, 0), 0);
    for (uint32_t d = 0; d < rule_.z.size(); ++d) shift_.push_back(shift.uniform(d));
  }

 protected:
  void fill_uniforms(uint64_t p0, size_t c, double* const* urow, double* jac) const override {
    uint64_t phi[kB];
    for (size_t i = 0; i < c; ++i) phi[i] = sobol_burley::reverse_bits(static_cast<uint32_t>(p0 + i));
    for (size_t d = 0; d < rule_.z.size(); ++d) {
      const uint64_t z = rule_.z[d];
      for (size_t i = 0; i < c; ++i) {
        double u = static_cast<double>((phi[i] * z) & 0xffffffffu) * 0x1.0p-32 + shift_[d];
        u -= u >= 1.0 ? 1.0 : 0.0;
        urow[d][i] = periodized(u, per_, &jac[i]);
      }
    }
  }
  uint64_t slot(uint64_t p) const override { return p; }
  const char* point_set() const override { return "lattice"; }

 private:
  EmbeddedLatticeRule rule_;
  Periodization per_;
  std::vector<double> shift_;
};

}  // namespace

std::shared_ptr<const Kernel> make_cone_kernel(IntegrationProblem p, ConeRuleOptions o) {
  return std::make_shared<ConeKernel>(std::move(p), o);
}

std::shared_ptr<const Kernel> make_lattice_cone_kernel(IntegrationProblem p, EmbeddedLatticeRule rule,
                                                       Periodization per, ConeRuleOptions o) {
  return std::make_shared<LatticeConeKernel>(std::move(p), std::move(rule), per, o);
}

}  // namespace tally
