#pragma once
// The estimators of an integration job, each a Kernel with one channel whose
// samples are unbiased estimates of the integral:
//   uniform      f(x) * |D|                     x uniform in D
//   importance   f(x) / p(x)                    x ~ p (power law, tabulated, cosine)
//   stratified   |D| * mean of f over one jittered sweep of k^s strata
//   qmc          |D| * mean of f over one scrambled Sobol point set (one randomization)
//   lattice      |D| * mean of f over one randomly shifted rank-1 lattice (one shift)
//   rejection    f(x) * |D|                     x from the bounding box, accepted if in D
// Sweep-based estimators (stratified, qmc, lattice) count one sweep as one sample, so the
// spread across sweeps gives an honest error bar (independent randomizations).
#include <memory>
#include <optional>
#include <vector>

#include "common/engine/kernel.hpp"
#include "common/integrate/domain.hpp"
#include "common/integrate/integrand.hpp"
#include "common/integrate/lattice_rule.hpp"

namespace tally {

struct IntegrationProblem {
  std::shared_ptr<const Integrand> integrand;
  std::shared_ptr<const Domain> domain;
  uint64_t seed = 1;
  // Vector integrands: also tally f_a + f_c for every pair a < c, so that the result has
  // the covariance of the component means (m (m - 1) / 2 more channels).
  bool covariance = false;
};

// One-dimensional density factor of an importance-sampling density on a box.
struct PowerDensity {
  std::vector<double> exponents;  // per dimension, p_k(x) ∝ (x - lower_k)^e, e > -1
};
struct TabulatedDensity {
  std::vector<double> values;  // piecewise constant, row-major (1-D: nu values)
  size_t nu = 0, nv = 0;       // nv = 0 for 1-D
};
struct CosineDensity {};  // hemisphere domain: p = cos(theta) / (pi r^2) per area

std::shared_ptr<const Kernel> make_uniform_kernel(IntegrationProblem p);
std::shared_ptr<const Kernel> make_power_importance_kernel(IntegrationProblem p, PowerDensity d);
std::shared_ptr<const Kernel> make_tabulated_importance_kernel(IntegrationProblem p, TabulatedDensity d);
std::shared_ptr<const Kernel> make_cosine_importance_kernel(IntegrationProblem p);
std::shared_ptr<const Kernel> make_stratified_kernel(IntegrationProblem p, uint32_t strata_per_dim,
                                                     uint32_t stratified_dims);
// One sample of a sweep estimator (qmc, lattice, stratified) is one whole point set,
// computed by one block: its coordinates are bounded so that cancel and shutdown (which
// act between blocks) stay prompt. The largest Sobol' set is 2^20 points.
inline constexpr uint64_t kMaxSweepCoordinates = uint64_t{1} << 24;
inline constexpr uint32_t kMaxQmcPoints = uint32_t{1} << 20;
// owen = false: affine matrix scramble (fast, default); true: nested uniform scramble.
// interlacing 2 or 3 (affine only): a higher-order net, InterlacedSobolSet (qmc.hpp).
std::shared_ptr<const Kernel> make_qmc_kernel(IntegrationProblem p, uint32_t points, bool owen = false,
                                              uint32_t interlacing = 1);
// rule.z has one entry per uniform of the domain; per: the periodizing transform.
std::shared_ptr<const Kernel> make_lattice_kernel(IntegrationProblem p, LatticeRule rule, Periodization per);
std::shared_ptr<const Kernel> make_rejection_kernel(IntegrationProblem p, uint32_t max_attempts);
// Tensor-product trapezoid rule with n points per dimension (deterministic; one
// "sample"), T(n) and T(m), m = (n + 1) / 2, for an error estimate. The grids are
// cut into partitions of at most 2^17 points (bounded blocks); a grid that fits in
// one has channel 0: T(n), channel 1: T(m), else headline() and error_summary()
// give the sums (see estimators.cpp).
std::shared_ptr<const Kernel> make_trapezoid_kernel(IntegrationProblem p, uint32_t points_per_dim);

}  // namespace tally
