#include "common/integrate/auto_estimator.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <fmt/format.h>
#include <limits>
#include <map>

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
constexpr uint64_t kRefinePoints = uint64_t{1} << 16;
constexpr double kRefineRatio = 4.0;  // the refinement costs at most 1/4 of the job it plans
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

// The evaluations candidate c needs to reach half-width eps at its best point-set size,
// from the sd at its largest pilot size and the rate between its two largest; sets
// c.rate, c.points and c.predicted_evaluations.
void predict(AutoCandidate& c, uint32_t uniforms, double eps, double t) {
  const size_t m = c.pilot_sd.size();
  if (m == 0 || !std::all_of(c.pilot_sd.begin(), c.pilot_sd.end(), [](double v) { return std::isfinite(v); })) {
    c.predicted_evaluations = kInf;
    return;
  }
  const double sd_last = c.pilot_sd[m - 1];
  if (c.estimator == "uniform") {
    c.rate = 0.5;
    c.points = 1;
    const double n = std::ceil(std::pow(t * sd_last / eps, 2.0));
    c.predicted_evaluations = std::max<double>(static_cast<double>(kMinRandomizations), n);
    return;
  }
  const double sd_prev = c.pilot_sd[m - 2];
  const double ratio = static_cast<double>(c.pilot_points[m - 1]) / static_cast<double>(c.pilot_points[m - 2]);
  double rate = 1.5;  // sd 0 at the large size: as fast as the clamp allows
  if (sd_last > 0.0 && sd_prev > 0.0) rate = std::log(sd_prev / sd_last) / std::log(ratio);
  c.rate = std::clamp(rate, 0.5, 1.5);
  double best = kInf;
  // Sobol' sets grow to the sweep bound (kMaxQmcPoints, kMaxSweepCoordinates); lattices
  // stop at kMaxLatticePoints, where their CBC construction already takes 0.3 s.
  const uint64_t max_points = c.estimator == "qmc" ? kMaxQmcPoints : kMaxLatticePoints;
  for (uint64_t want = uint64_t{1} << 10; want <= max_points; want *= 2) {
    if (want * uniforms > kMaxSweepCoordinates) break;  // the sweep estimators' point-set bound
    const uint64_t points = c.estimator == "qmc" ? want : largest_prime_at_most(static_cast<uint32_t>(want));
    const double sd =
        sd_last * std::pow(static_cast<double>(points) / static_cast<double>(c.pilot_points[m - 1]), -c.rate);
    const double k = std::max<double>(static_cast<double>(kMinRandomizations), std::ceil(std::pow(t * sd / eps, 2.0)));
    const double evals = k * static_cast<double>(points);
    if (evals < best) {
      best = evals;
      c.points = points;
    }
  }
  c.predicted_evaluations = best;
}

double fewest(const std::vector<AutoCandidate>& cs) {
  double best = kInf;
  for (const AutoCandidate& c : cs) best = std::min(best, c.predicted_evaluations);
  return best;
}

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
  uni.pilot_points = {1};
  uni.pilot_sd = {u.sd};
  sel.pilot_evaluations += u.evaluations;
  sel.candidates.push_back(uni);

  // Randomized QMC: 8 randomizations at each pilot size. A candidate's kernel at a size
  // (lattice rules are built once per size and shared by both periodizations).
  double best_mean = u.mean, best_se = u.sd / std::sqrt(static_cast<double>(kPilotUniformPoints));
  const std::vector<double> weights(U, kDefaultLatticeWeight);
  std::map<uint32_t, LatticeRule> rules;
  const auto run_at = [&](AutoCandidate& c, uint64_t want) {
    std::shared_ptr<const Kernel> k;
    uint64_t points = want;
    if (c.estimator == "qmc") {
      k = make_qmc_kernel(pp, static_cast<uint32_t>(want));
    } else {
      const uint32_t n = largest_prime_at_most(static_cast<uint32_t>(want));
      auto it = rules.find(n);
      if (it == rules.end()) it = rules.emplace(n, cbc_lattice_rule(n, weights)).first;
      points = n;
      k = make_lattice_kernel(pp, it->second, c.periodize == "baker" ? Periodization::baker : Periodization::none);
    }
    const PilotRun r = pilot(*k, kPilotShifts, points);
    sel.pilot_evaluations += r.evaluations;
    c.pilot_points.push_back(points);
    c.pilot_sd.push_back(r.sd);
    const double se = r.sd / std::sqrt(static_cast<double>(kPilotShifts));
    if (std::isfinite(se) && se < best_se) {
      best_se = se;
      best_mean = r.mean;
    }
  };
  const std::vector<std::pair<std::string, std::string>> rqmc = {{"qmc", ""}, {"lattice", "baker"}, {"lattice", "none"}};
  for (const auto& [name, periodize] : rqmc) {
    AutoCandidate c;
    c.estimator = name;
    c.periodize = periodize;
    run_at(c, kSmall);
    run_at(c, kLarge);
    sel.candidates.push_back(std::move(c));
  }

  // The target half-width: the looser of the two (the job stops when either is met).
  double eps = 0.0;
  if (target.abs_error > 0.0) eps = target.abs_error;
  if (target.rel_error > 0.0) eps = std::max(eps, target.rel_error * std::fabs(best_mean));
  if (!(eps > 0.0)) eps = 1e-4 * std::fabs(best_mean);
  if (!(eps > 0.0)) eps = 1e-4;  // an integral of 0: an absolute nominal target
  sel.target_half_width = eps;
  const double t = critical_value(target.confidence, kMinRandomizations);
  for (AutoCandidate& c : sel.candidates) predict(c, U, eps, t);

  // A rate fitted between 2^10 and 2^13 points can be far off at 2^16 and beyond (the
  // Genz gaussian at d = 12: 1.41 fitted, the lattice ran out of time). When the job will
  // cost at least kRefineRatio times more, each usable RQMC candidate runs a third size,
  // kRefinePoints (or the sweep bound), and the rate is fitted between 2^13 and it.
  const uint64_t third = std::min<uint64_t>(kRefinePoints, std::bit_floor(kMaxSweepCoordinates / std::max(1u, U)));
  if (third > kLarge) {
    double refine_cost = 0.0;
    for (const AutoCandidate& c : sel.candidates) {
      if (c.estimator != "uniform" && std::isfinite(c.predicted_evaluations)) {
        refine_cost += static_cast<double>(kPilotShifts * third);
      }
    }
    if (refine_cost > 0.0 && fewest(sel.candidates) >= kRefineRatio * refine_cost) {
      for (AutoCandidate& c : sel.candidates) {
        if (c.estimator == "uniform" || !std::isfinite(c.predicted_evaluations)) continue;
        run_at(c, third);
        predict(c, U, eps, t);
      }
    }
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
