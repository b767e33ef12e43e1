#include "common/integrate/cone_rule.hpp"

#include <algorithm>
#include <cmath>
#include <fmt/format.h>
#include <stdexcept>
#include <vector>

#include "common/engine/block_abandon.hpp"
#include "common/engine/job_state.hpp"
#include "common/integrate/integration_counters.hpp"
#include "common/integrate/rule_kernel.hpp"
#include "common/rng/counter_rng.hpp"
#include "common/sampling/qmc.hpp"

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

// The coefficient order kappa, refined at level l (cubSobol_g): among the first 2^(l+1)
// positions, where the coefficient at position 2^l + j (0 < j < 2^l) is larger than the
// one at position j, the two swap, and so do the same pairs in every later block of
// 2^(l+1) positions. The pairs to swap are all found before any is swapped.
void refine_order(std::vector<uint32_t>& kappa, const std::vector<double>& y, uint32_t l, size_t n) {
  const size_t nl = size_t{1} << l;
  std::vector<size_t> flip;
  for (size_t j = 1; j < nl; ++j) {
    if (std::fabs(y[kappa[nl + j]]) > std::fabs(y[kappa[j]])) flip.push_back(j);
  }
  for (size_t b = 0; b < n; b += 2 * nl) {
    for (size_t j : flip) std::swap(kappa[b + j], kappa[b + nl + j]);
  }
}

// Sum of |coefficient| at kappa positions [2^(l-1), 2^l), l >= 1.
double band_sum(const std::vector<uint32_t>& kappa, const std::vector<double>& y, uint32_t l) {
  double s = 0.0;
  for (size_t i = size_t{1} << (l - 1); i < (size_t{1} << l); ++i) s += std::fabs(y[kappa[i]]);
  return s;
}

}  // namespace

ConeRuleResult run_cone_rule(const ConeRuleOptions& o, const ConeValues& values) {
  if (!(o.lag + 1 <= o.m_min && o.m_min <= o.m_max && o.m_max <= 30) || !(o.fudge > 0.0)) {
    throw std::invalid_argument("run_cone_rule: needs lag + 1 <= m_min <= m_max <= 30 and fudge > 0");
  }
  ConeRuleResult r;
  std::vector<double> y(size_t{1} << o.m_min);
  std::vector<uint32_t> kappa(y.size());
  if (!values(0, y.size(), y.data())) {
    r.aborted = true;
    return r;
  }
  walsh_hadamard_normalized(y);
  for (size_t i = 0; i < kappa.size(); ++i) kappa[i] = static_cast<uint32_t>(i);
  for (uint32_t l = o.m_min - 1; l >= 1; --l) refine_order(kappa, y, l, y.size());

  for (uint32_t m = o.m_min;; ++m) {
    const size_t n = size_t{1} << m;
    if (m > o.m_min) {  // double: the new half's values, their transform, one more level
      const size_t h = n / 2;
      y.resize(n);
      if (!values(h, h, y.data() + h)) {
        r.aborted = true;
        return r;
      }
      walsh_hadamard_normalized(std::span<double>(y).subspan(h, h));
      for (size_t i = 0; i < h; ++i) {  // as in walsh_hadamard_normalized
        const double a = 0.5 * y[i], c = 0.5 * y[i + h];
        y[i] = a + c;
        y[i + h] = a - c;
      }
      kappa.resize(n);
      for (size_t i = 0; i < h; ++i) kappa[h + i] = kappa[i] + static_cast<uint32_t>(h);
      for (uint32_t l = m - 1; l >= m - o.lag; --l) refine_order(kappa, y, l, n);
    }
    const double S = band_sum(kappa, y, m - o.lag);
    r.m = m;
    r.mean = y[0];
    r.error_bound = o.fudge * std::ldexp(S, -static_cast<int>(m));
    // Met when the bound is within the target for every value the bound allows: the
    // relative target is taken against the smallest |I| consistent with it.
    const double tol = std::max(o.abs_error, o.rel_error * (std::fabs(r.mean) - r.error_bound));
    r.met = (o.abs_error > 0.0 || o.rel_error > 0.0) && r.error_bound <= tol;
    if (r.met || m == o.m_max) return r;
  }
}

namespace {

constexpr size_t kB = kIntegrandBatch;

// The cone rule as a job's kernel: one block of one pass runs the whole rule (like
// cubature: the coefficients live in memory for the rule's length, not checkpointed;
// the block polls block_abandoned() between batches, so cancel stays prompt). Channels:
// 0 the mean, 1 the error bound.
class ConeKernel final : public RuleKernelBase {
 public:
  ConeKernel(IntegrationProblem p, ConeRuleOptions o) : RuleKernelBase(1), p_(std::move(p)), o_(o) {
    if (p_.integrand->components() != 1) throw std::invalid_argument("the cone rule takes a scalar integrand");
  }

 protected:
  void run_rule(BlockResult& out) const override {
    const Domain& D = *p_.domain;
    const uint32_t U = D.uniforms();
    const size_t dims = D.dimensions();
    // One randomization, seeded as the qmc estimator's first point set.
    const ScrambledSobolSet set(mix64(stream_key(p_.seed, 0) ^ mix64(0 + 0x51ed27)), U);
    std::vector<double> u(U * kB), x(dims * kB), f(kB);
    std::vector<double*> urow(U), xrow(dims);
    std::vector<const double*> ucrow(U), xcrow(dims);
    for (uint32_t k = 0; k < U; ++k) ucrow[k] = urow[k] = u.data() + k * kB;
    for (size_t k = 0; k < dims; ++k) xcrow[k] = xrow[k] = x.data() + k * kB;
    const double measure = D.measure();
    // Values at natural indices [first, first + n): the set fills positions in Gray-code
    // order, and positions [first, first + n) of a doubling are the same indices
    // (index = position ^ (position >> 1)), so each value lands at its index.
    auto values = [&](uint64_t first, uint64_t n, double* dst) {
      for (uint64_t p0 = first; p0 < first + n; p0 += kB) {
        if (block_abandoned()) return false;
        const size_t c = static_cast<size_t>(std::min<uint64_t>(kB, first + n - p0));
        set.fill(static_cast<uint32_t>(p0), c, urow.data());
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
            fault.message = fmt::format("the integrand is {} at {} (point {} of the cone rule's Sobol' set)",
                                        std::isnan(f[i]) ? "NaN" : "infinite", where, p0 + i);
            out.fault = std::move(fault);
            return false;
          }
          const uint64_t p = p0 + i;
          dst[(p ^ (p >> 1)) - first] = measure * f[i];
        }
      }
      return true;
    };
    const ConeRuleResult r = run_cone_rule(o_, values);
    if (r.aborted) return;  // a fault (out.fault says where) or an abandoned block (dropped)
    out.tallies[0].add(r.mean);
    out.tallies[1].add(r.error_bound);
  }

 private:
  IntegrationProblem p_;
  ConeRuleOptions o_;
};

}  // namespace

std::shared_ptr<const Kernel> make_cone_kernel(IntegrationProblem p, ConeRuleOptions o) {
  return std::make_shared<ConeKernel>(std::move(p), o);
}

}  // namespace tally
