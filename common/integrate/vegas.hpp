#pragma once
// VEGAS (Lepage 1978): adaptive importance sampling on a separable grid over a box.
// Each axis of the unit cube is cut into `bins` intervals of equal probability; a
// point picks a bin and a uniform offset in it per axis, so its density is
// prod_k 1 / (bins * width_k(bin)). After every pass the grid is refined from that
// pass's per-bin sums of (f / p)^2, merged in block order (Kernel::fold_pass): the
// grid of pass k is fixed before pass k draws a sample, and it lives in
// JobState::kernel_state, so any thread or worker count and any resume give the
// same bits. `stratify` adds VEGAS+'s adaptive stratification (below).
//
// The estimate (the stated rule): the first `warmup_passes` passes only adapt the
// grid. Default (`combine: weighted`): the later passes' means weighted by
// w_k = n_k / s_{k-1}^2 (s_{k-1}^2 the previous pass's variance per sample, known
// before pass k draws a sample), I = sum w_k I_k / sum w_k, standard error
// sqrt(sum w_k^2 se_k^2) / sum w_k. Weights fixed in advance keep I unbiased, unlike
// Lepage's 1/se_k^2 from the pass's own samples; a poor grid's pass counts little.
// `combine: pooled`: every later sample with equal weight (channel 0; exactly
// unbiased, its sample variance / n estimates the variance of the mean). Channel c
// always holds the pooled samples of component c. The post-warm-up passes are
// also compared with each other: chi^2 = sum_k (I_k - I_w)^2 / se_k^2 over K passes
// (I_w their inverse-variance weighted mean), K - 1 degrees of freedom. When its
// p-value is below 0.001 the job warns and its error bar is scaled by
// sqrt(chi^2 / dof) (never a silent "target met").
#include <cstdint>
#include <memory>
#include <optional>
#include <vector>

#include "common/engine/job_state.hpp"
#include "common/engine/kernel.hpp"
#include "common/integrate/estimators.hpp"

namespace tally {

struct VegasOptions {
  // Defaults from `tally-study vegas-tune` on the Genz tuning instances (seeds
  // 101-105): 200 bins and alpha 1.0 were the most reliable on the discontinuous
  // family (GSL's 50 bins / 1.5 reached 3 digits on 8 of 15, these on 13 of 15).
  uint32_t bins = 200;          // per axis
  double alpha = 1.0;           // damping of the grid refinement (0: never adapt)
  uint32_t warmup_passes = 3;   // passes that only adapt the grid
  uint64_t max_pass_samples = uint64_t{1} << 17;  // passes double from 4096 up to this
  // true: inverse-variance weighted mean of the post-warm-up passes (Lepage's rule);
  // false: their samples pooled with equal weight (exactly unbiased, slower when a
  // pass's grid was poor).
  bool weighted = true;
  // Steering of vector integrands: the grid follows the sum over components of
  // (f_c / p)^2 / s_c^2, s_c = the component's scale from the previous pass.

  // VEGAS+ adaptive stratification (Lepage 2021, arXiv:2009.05112): the unit cube of
  // the grid's variables y is cut into H = s^d hypercubes (s = floor((R/4)^(1/d)),
  // R = kVegasRound samples), and every round of R consecutive samples of a pass puts
  // n_h = 2 + floor((R - 2H) * sigma_h^beta / sum sigma^beta) (cumulated, so the n_h
  // add up to R) samples in hypercube h, sigma_h the spread of f/p in h measured in the
  // previous pass (equal n_h in the first). Passes are whole rounds. The pass estimate
  // is sum_h |h| mean_h with variance sum_h |h|^2 s_h^2 / n_h (n_h >= 2, fixed before
  // the pass draws), combined across passes by the rule above.
  bool stratify = false;
  double beta = 0.75;
};

inline constexpr uint64_t kVegasRound = 4096;  // samples per stratification round

struct VegasIteration {
  Tally tally;  // the pass's samples of f / p (component 0 for vector integrands)
  bool warmup = false;
};

// What a VEGAS job did, decoded from JobState::kernel_state.
struct VegasReport {
  uint32_t bins = 0;
  uint32_t dimensions = 0;
  std::vector<VegasIteration> iterations;
  uint32_t used = 0;             // post-warm-up iterations pooled into the estimate
  double chi2 = 0.0;             // over the used iterations (NaN if fewer than 2)
  double chi2_per_dof = 0.0;
  double p_value = 1.0;
  bool inconsistent = false;     // p_value < kVegasChi2Alarm
  double error_scale = 1.0;      // sqrt(chi2/dof) when inconsistent, else 1
  // Per component: the weighted mean of the post-warm-up passes (weights fixed before
  // each pass, see above) and its standard error (before error_scale).
  std::vector<double> combined_mean, combined_std_error;
  std::vector<std::vector<double>> grid;  // per axis: bins + 1 edges in [0, 1]
  // VEGAS+ (stratify): strata per axis, hypercubes, and the samples per hypercube in one
  // round of the next pass (empty without stratification).
  uint32_t strata_per_axis = 0;
  uint64_t hypercubes = 0;
  std::vector<uint64_t> next_allocation;
};

inline constexpr double kVegasChi2Alarm = 1e-3;

std::shared_ptr<const Kernel> make_vegas_kernel(IntegrationProblem p, VegasOptions o);
// nullopt when the state holds no VEGAS grid (no pass finished yet, or another kernel).
std::optional<VegasReport> vegas_report(const JobState& state);

// n points of the unit cube drawn from a grid exactly as the kernel draws them for a
// job with `seed` (samples first .. first + n - 1), with the density the kernel
// divides by: points[k][i], pdf[i]. Tests check the sampling against the density.
void vegas_draw(const std::vector<std::vector<double>>& grid, uint64_t seed, uint64_t first, size_t n,
                std::vector<std::vector<double>>& points, std::vector<double>& pdf);
// VEGAS+: the same with stratification, `alloc` the samples per hypercube of one round
// (kVegasRound in all, >= 2 each), the pass starting at sample `pass_start`; pdf[i] is
// the density of sample i's position drawn at random within the round:
// grid density * H * n_h / R.
void vegas_plus_draw(const std::vector<std::vector<double>>& grid, uint32_t strata_per_axis,
                     const std::vector<uint64_t>& alloc, uint64_t seed, uint64_t pass_start, uint64_t first,
                     size_t n, std::vector<std::vector<double>>& points, std::vector<double>& pdf);
// Strata per axis VEGAS+ uses in d dimensions: floor((kVegasRound / 4)^(1/d)).
uint32_t vegas_strata_per_axis(size_t d);
// The grid's density at a point of the unit cube (tests: chi-square of the sampling).
double vegas_grid_density(const std::vector<std::vector<double>>& grid, const double* unit_point);

}  // namespace tally
