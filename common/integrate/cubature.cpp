#include "common/integrate/cubature.hpp"

#include <cubature.h>

#include <algorithm>
#include <cmath>
#include <fmt/format.h>
#include <limits>
#include <stdexcept>
#include <vector>

#include "common/integrate/integration_counters.hpp"
#include "common/integrate/rule_kernel.hpp"

namespace tally {

namespace {

constexpr size_t kB = kIntegrandBatch;

struct CallbackData {
  const Integrand* f = nullptr;
  const Domain* D = nullptr;
  BlockResult* out = nullptr;
  uint64_t evaluations = 0;
  uint64_t hard_cap = 0;
  bool over_cap = false;
  std::vector<double> xs, vals;
  std::vector<const double*> xptr;
  std::vector<double*> vptr;
};

// The library hands points row-major (x[i * dim + k]) and wants fval[i * fdim + c];
// the integrand takes structure-of-arrays batches: transpose in batches of kB.
int evaluate(unsigned dim, size_t npts, const double* x, void* data, unsigned fdim, double* fval) {
  auto* cd = static_cast<CallbackData*>(data);
  cd->evaluations += npts;
  if (cd->evaluations > cd->hard_cap) {  // never expected: the library honours maxEval
    cd->over_cap = true;
    return 1;
  }
  cd->out->counters.add(IntegrationCounter::evaluations, npts);
  for (size_t off = 0; off < npts; off += kB) {
    const size_t n = std::min(kB, npts - off);
    for (size_t k = 0; k < dim; ++k) {
      double* col = cd->xs.data() + k * kB;
      for (size_t i = 0; i < n; ++i) col[i] = x[(off + i) * dim + k];
    }
    cd->f->evaluate_components(cd->xptr.data(), n, cd->vptr.data());
    for (size_t c = 0; c < fdim; ++c) {
      const double* v = cd->vals.data() + c * kB;
      for (size_t i = 0; i < n; ++i) {
        if (!std::isfinite(v[i])) {
          BlockResult& out = *cd->out;
          out.counters.add(IntegrationCounter::nonfinite);
          SampleFault f;
          f.sample_index = 0;
          f.channel = static_cast<uint32_t>(c);
          f.value = v[i];
          std::string where;
          for (size_t k = 0; k < dim; ++k) {
            f.point.push_back(x[(off + i) * dim + k]);
            where += fmt::format("{}x{} = {:.17g}", k ? ", " : "", k, f.point[k]);
          }
          f.message = fmt::format("the integrand{} is {} at {} (cubature node)",
                                  fdim > 1 ? fmt::format(" component {}", c) : std::string(),
                                  std::isnan(v[i]) ? "NaN" : "infinite", where);
          out.fault = std::move(f);
          return 1;  // stops the library; the job fails with the point
        }
        fval[(off + i) * fdim + c] = v[i];
      }
    }
  }
  return 0;
}

class CubatureKernel final : public RuleKernelBase {
 public:
  CubatureKernel(IntegrationProblem p, CubatureOptions o)
      : RuleKernelBase(p.integrand->components()), p_(std::move(p)), o_(o), d_(p_.domain->dimensions()) {
    if (!p_.domain->is_box()) throw std::invalid_argument("cubature needs a box domain");
    if (d_ > kMaxCubatureDimensions) throw std::invalid_argument("cubature supports at most 8 dimensions");
  }

 protected:
  void run_rule(BlockResult& out) const override {
    CallbackData cd;
    cd.f = p_.integrand.get();
    cd.D = p_.domain.get();
    cd.out = &out;
    cd.hard_cap = 2 * o_.max_evaluations + 100000;
    cd.xs.resize(d_ * kB);
    cd.vals.resize(m_ * kB);
    for (size_t k = 0; k < d_; ++k) cd.xptr.push_back(cd.xs.data() + k * kB);
    for (size_t c = 0; c < m_; ++c) cd.vptr.push_back(cd.vals.data() + c * kB);
    std::vector<double> val(m_, 0.0), err(m_, 0.0);
    const auto fdim = static_cast<unsigned>(m_);
    const auto dim = static_cast<unsigned>(d_);
    const int rc =
        o_.p_adaptive
            ? pcubature_v(fdim, &evaluate, &cd, dim, p_.domain->lower().data(), p_.domain->upper().data(),
                          static_cast<size_t>(o_.max_evaluations), o_.abs_error, o_.rel_error, ERROR_INDIVIDUAL,
                          val.data(), err.data())
            : hcubature_v(fdim, &evaluate, &cd, dim, p_.domain->lower().data(), p_.domain->upper().data(),
                          static_cast<size_t>(o_.max_evaluations), o_.abs_error, o_.rel_error, ERROR_INDIVIDUAL,
                          val.data(), err.data());
    if (out.fault) return;
    if (rc != 0 || cd.over_cap) {
      SampleFault f;
      f.message = cd.over_cap ? fmt::format("cubature evaluated more than {} points", cd.hard_cap)
                              : "the cubature library failed (out of memory?)";
      out.fault = std::move(f);
      return;
    }
    for (size_t c = 0; c < m_; ++c) {
      out.tallies[c].add(val[c]);
      out.tallies[m_ + c].add(err[c]);
    }
  }

 private:
  IntegrationProblem p_;
  CubatureOptions o_;
  size_t d_;
};

}  // namespace

std::shared_ptr<const Kernel> make_cubature_kernel(IntegrationProblem p, CubatureOptions o) {
  return std::make_shared<CubatureKernel>(std::move(p), o);
}

}  // namespace tally
