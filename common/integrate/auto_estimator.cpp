#include "common/integrate/auto_estimator.hpp"

#include <algorithm>
#include <cmath>
#include <fmt/format.h>
#include <limits>

#include "common/engine/kernel.hpp"
#include "common/integrate/lattice_rule.hpp"
#include "common/rng/counter_rng.hpp"
#include "common/stats/confidence.hpp"

namespace tally {

namespace {

constexpr uint64_t kPilotShifts = 8;
constexpr uint64_t kPilotUniformPoints = 16384;
constexpr uint32_t kSmall = 1024, kLarge = 8192;
constexpr uint64_t kMinRandomizations = 16;
constexpr double kInf = std::numeric_limits<double>::infinity();

struct PilotRun {
  double mean = 0.0, sd = kInf;
  uint64_t evaluations = 0;
};

PilotRun pilot(const Kernel& k, uint64_t samples, uint64_t points) {
  Block b;
  b.sample_count = samples;
  BlockResult out;
  k.run_block(b, out);
  PilotRun r;
  r.evaluations = samples * points;
  if (out.fault || out.tallies.empty() || out.tallies[0].n != samples) return r;  // unusable
  r.mean = out.tallies[0].mean;
  r.sd = std::sqrt(std::max(0.0, out.tallies[0].variance()));
  return r;
}

std::string count_text(double v) { return std::isfinite(v) ? fmt::format("{:.3g}", v) : "never"; }

}  // namespace

AutoSelection select_estimator(const IntegrationProblem& problem, const AutoTarget& target) {
  IntegrationProblem pp = problem;
  pp.seed = mix64(problem.seed ^ 0x61757430706c6f74ULL);  // the pilot's own stream ("auto0plot")
  const uint32_t U = problem.domain->uniforms();
  AutoSelection sel;

  // Uniform: the sd of one point.
  AutoCandidate uni;
  uni.estimator = "uniform";
  const PilotRun u = pilot(*make_uniform_kernel(pp), kPilotUniformPoints, 1);
  uni.pilot_points_small = uni.pilot_points_large = 1;
  uni.sd_small = uni.sd_large = u.sd;
  sel.pilot_evaluations += u.evaluations;
  sel.candidates.push_back(uni);

  // Randomized QMC: 8 randomizations at two sizes.
  struct Rqmc {
    std::string name, periodize;
  };
  const std::vector<Rqmc> rqmc = {{"qmc", ""}, {"lattice", "baker"}, {"lattice", "none"}};
  double best_mean = u.mean, best_sd = u.sd / std::sqrt(static_cast<double>(kPilotUniformPoints));
  const std::vector<double> weights(U, kDefaultLatticeWeight);
  const LatticeRule small_rule = cbc_lattice_rule(largest_prime_at_most(kSmall), weights);
  const LatticeRule large_rule = cbc_lattice_rule(largest_prime_at_most(kLarge), weights);
  for (const Rqmc& q : rqmc) {
    AutoCandidate c;
    c.estimator = q.name;
    c.periodize = q.periodize;
    PilotRun runs[2];
    for (int size = 0; size < 2; ++size) {
      std::shared_ptr<const Kernel> k;
      uint64_t points = 0;
      if (q.name == "qmc") {
        points = size == 0 ? kSmall : kLarge;
        k = make_qmc_kernel(pp, static_cast<uint32_t>(points));
      } else {
        const LatticeRule& rule = size == 0 ? small_rule : large_rule;
        points = rule.n;
        k = make_lattice_kernel(pp, rule, q.periodize == "baker" ? Periodization::baker : Periodization::none);
      }
      runs[size] = pilot(*k, kPilotShifts, points);
      sel.pilot_evaluations += runs[size].evaluations;
      (size == 0 ? c.pilot_points_small : c.pilot_points_large) = points;
    }
    c.sd_small = runs[0].sd;
    c.sd_large = runs[1].sd;
    const double se = runs[1].sd / std::sqrt(static_cast<double>(kPilotShifts));
    if (std::isfinite(se) && se < best_sd) {
      best_sd = se;
      best_mean = runs[1].mean;
    }
    sel.candidates.push_back(c);
  }

  // The target half-width: the looser of the two (the job stops when either is met).
  double eps = 0.0;
  if (target.abs_error > 0.0) eps = target.abs_error;
  if (target.rel_error > 0.0) eps = std::max(eps, target.rel_error * std::fabs(best_mean));
  if (!(eps > 0.0)) eps = 1e-4 * std::fabs(best_mean);
  if (!(eps > 0.0)) eps = 1e-4;  // an integral of 0: an absolute nominal target
  sel.target_half_width = eps;
  const double t = critical_value(target.confidence, kMinRandomizations);

  for (AutoCandidate& c : sel.candidates) {
    if (!std::isfinite(c.sd_small) || !std::isfinite(c.sd_large)) {
      c.predicted_evaluations = kInf;
      continue;
    }
    if (c.estimator == "uniform") {
      c.rate = 0.5;
      c.points = 1;
      const double n = std::ceil(std::pow(t * c.sd_large / eps, 2.0));
      c.predicted_evaluations = std::max<double>(static_cast<double>(kMinRandomizations), n);
      continue;
    }
    const double ratio = static_cast<double>(c.pilot_points_large) / static_cast<double>(c.pilot_points_small);
    double rate = 1.5;  // sd 0 at the large size: as fast as the clamp allows
    if (c.sd_large > 0.0 && c.sd_small > 0.0) rate = std::log(c.sd_small / c.sd_large) / std::log(ratio);
    c.rate = std::clamp(rate, 0.5, 1.5);
    double best = kInf;
    for (uint32_t e = 10; e <= 16; ++e) {
      const uint64_t want = uint64_t{1} << e;
      if (want * U > (uint64_t{1} << 24)) break;  // the sweep estimators' point-set bound
      const uint64_t points = c.estimator == "qmc" ? want : largest_prime_at_most(static_cast<uint32_t>(want));
      const double sd = c.sd_large * std::pow(static_cast<double>(points) / static_cast<double>(c.pilot_points_large),
                                              -c.rate);
      const double k = std::max<double>(static_cast<double>(kMinRandomizations), std::ceil(std::pow(t * sd / eps, 2.0)));
      const double evals = k * static_cast<double>(points);
      if (evals < best) {
        best = evals;
        c.points = points;
      }
    }
    c.predicted_evaluations = best;
  }
  // Fewest predicted evaluations; a later candidate must win by more than rounding.
  for (size_t i = 1; i < sel.candidates.size(); ++i) {
    if (sel.candidates[i].predicted_evaluations < sel.candidates[sel.chosen].predicted_evaluations * (1.0 - 1e-9)) {
      sel.chosen = i;
    }
  }
  const AutoCandidate& w = sel.candidates[sel.chosen];
  std::string others;
  for (size_t i = 0; i < sel.candidates.size(); ++i) {
    if (i == sel.chosen) continue;
    const AutoCandidate& c = sel.candidates[i];
    others += fmt::format("{}{}{} {}", others.empty() ? "" : ", ", c.estimator,
                          c.periodize.empty() ? "" : fmt::format(" ({})", c.periodize),
                          count_text(c.predicted_evaluations));
  }
  const std::string label = w.estimator + (w.periodize.empty() ? "" : fmt::format(" ({})", w.periodize));
  sel.reason = fmt::format(
      "{} with {} points per sample: its pilot spread falls as evaluations^-{:.2f}, so it needs about {} "
      "evaluations to reach +-{:.3g} at {:g}%, against {}; pilot: {} evaluations",
      label, w.points, w.rate, count_text(w.predicted_evaluations), eps, 100.0 * target.confidence, others,
      sel.pilot_evaluations);
  return sel;
}

}  // namespace tally
