#include "common/integrate/auto_estimator.hpp"

#include <algorithm>
#include <atomic>
#include <bit>
#include <cmath>
#include <fmt/format.h>
#include <limits>
#include <list>
#include <map>
#include <mutex>
#include <optional>
#include <utility>

#include "common/engine/component_targets.hpp"
#include "common/engine/kernel.hpp"
#include "common/engine/stop_rule.hpp"
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

// One pilot run: per component, the mean and the sd of one sample (non-finite sd: the
// run failed).
struct PilotRun {
  std::vector<double> mean, sd;
  uint64_t evaluations = 0;
};

// A vector integrand's block keeps components x samples values until it ends: the pilot
// runs at most this many a block (merged in sample order), so that the uniform
// candidate's 16,384 one-point samples of 10,000 components take 16 MB, not 1.3 GB.
// A scalar integrand's pilot is one block, as before.
constexpr uint64_t kPilotValuesPerBlock = uint64_t{1} << 21;

PilotRun pilot(const Kernel& k, uint64_t samples, uint64_t points, size_t components) {
  const uint64_t per_block = std::max<uint64_t>(1, kPilotValuesPerBlock / std::max<size_t>(1, components));
  BlockResult out;
  for (uint64_t first = 0; first < samples && !out.fault; first += per_block) {
    Block b;
    b.index = first / per_block;
    b.first_sample = first;
    b.sample_count = std::min(per_block, samples - first);
    if (first == 0) {
      k.run_block(b, out);
    } else {
      BlockResult part;
      k.run_block(b, part);
      combine_results(out, part);
    }
  }
  PilotRun r;
  r.evaluations = samples * points;
  r.mean.assign(components, 0.0);
  r.sd.assign(components, kInf);
  if (out.fault || out.tallies.size() < components) return r;  // unusable
  for (size_t j = 0; j < components; ++j) {
    if (out.tallies[j].n != samples) continue;
    r.mean[j] = out.tallies[j].mean;
    r.sd[j] = std::sqrt(std::max(0.0, out.tallies[j].variance()));
  }
  return r;
}

std::string count_text(double v) { return std::isfinite(v) ? fmt::format("{:.3g}", v) : "never"; }

// A candidate's pilot: points per sample at each size run, and per size the sd of one
// sample of each component.
struct Pilot {
  std::vector<uint64_t> points;
  std::vector<std::vector<double>> sd;
};

// The evaluations candidate c needs for every component j to reach half-width eps[j] at
// its best point-set size, from each component's sd at the largest pilot size and its
// rate between the two largest; the component that needs the most randomizations sets
// the cost. Sets c's rate, points, predicted_evaluations, limiting_component and its
// pilot_points / pilot_sd (those of the limiting component).
void predict(AutoCandidate& c, const Pilot& p, const std::vector<double>& eps, uint32_t uniforms, double t) {
  const size_t sizes = p.points.size(), m = eps.size();
  c.pilot_points = p.points;
  c.predicted_evaluations = kInf;
  for (const auto& row : p.sd) {
    if (!std::all_of(row.begin(), row.end(), [](double v) { return std::isfinite(v); })) {
      c.pilot_sd.clear();
      for (const auto& r : p.sd) c.pilot_sd.push_back(r[0]);
      return;
    }
  }
  std::vector<double> rate(m, 0.5);
  if (c.estimator != "uniform") {
    const double ratio = static_cast<double>(p.points[sizes - 1]) / static_cast<double>(p.points[sizes - 2]);
    for (size_t j = 0; j < m; ++j) {
      const double last = p.sd[sizes - 1][j], prev = p.sd[sizes - 2][j];
      double r = 1.5;  // sd 0 at the large size: as fast as the clamp allows
      if (last > 0.0 && prev > 0.0) r = std::log(prev / last) / std::log(ratio);
      rate[j] = std::clamp(r, 0.5, 1.5);
    }
  }
  // Randomizations (uniform: points) component j needs with `points` per sample, before
  // the floor of kMinRandomizations.
  const auto needed = [&](size_t j, uint64_t points) {
    const double sd = p.sd[sizes - 1][j] *
                      std::pow(static_cast<double>(points) / static_cast<double>(p.points[sizes - 1]), -rate[j]);
    return std::pow(t * sd / eps[j], 2.0);
  };
  std::vector<uint64_t> sizes_to_try;
  if (c.estimator == "uniform") {
    sizes_to_try.push_back(1);
  } else {
    // Sobol' sets grow to the sweep bound (kMaxQmcPoints, kMaxSweepCoordinates); lattices
    // stop at kMaxLatticePoints, where their CBC construction already takes 0.3 s.
    const uint64_t max_points = c.estimator == "qmc" ? kMaxQmcPoints : kMaxLatticePoints;
    for (uint64_t want = uint64_t{1} << 10; want <= max_points; want *= 2) {
      if (want * uniforms > kMaxSweepCoordinates) break;  // the sweep estimators' point-set bound
      sizes_to_try.push_back(c.estimator == "qmc" ? want : largest_prime_at_most(static_cast<uint32_t>(want)));
    }
  }
  for (uint64_t points : sizes_to_try) {
    double most = -1.0;
    size_t worst = 0;
    for (size_t j = 0; j < m; ++j) {
      const double kj = needed(j, points);
      if (kj > most) {
        most = kj;
        worst = j;
      }
    }
    const double k = std::max<double>(static_cast<double>(kMinRandomizations), std::ceil(most));
    const double evals = k * static_cast<double>(points);
    if (evals < c.predicted_evaluations) {
      c.predicted_evaluations = evals;
      c.points = points;
      c.limiting_component = worst;
    }
  }
  c.rate = rate[c.limiting_component];
  c.pilot_sd.clear();
  for (const auto& row : p.sd) c.pilot_sd.push_back(row[c.limiting_component]);
}

double fewest(const std::vector<AutoCandidate>& cs) {
  double best = kInf;
  for (const AutoCandidate& c : cs) best = std::min(best, c.predicted_evaluations);
  return best;
}

std::atomic<uint64_t> g_pilots_run{0};

// The memo behind select_estimator_remembered: answers by key, most recently used first.
class SelectionMemo {
 public:
  struct Answer {
    AutoSelection selection;
    std::optional<std::pair<uint32_t, LatticeRule>> chosen_rule;  // a chosen lattice's rule
  };

  std::optional<Answer> find(const std::string& key) {
    std::lock_guard lock(mu_);
    const auto it = index_.find(key);
    if (it == index_.end()) return std::nullopt;
    order_.splice(order_.begin(), order_, it->second);
    return it->second->second;
  }

  void put(const std::string& key, Answer a) {
    std::lock_guard lock(mu_);
    if (const auto it = index_.find(key); it != index_.end()) {
      order_.splice(order_.begin(), order_, it->second);
      return;
    }
    order_.emplace_front(key, std::move(a));
    index_.emplace(key, order_.begin());
    while (order_.size() > kSelectionMemoEntries) {
      index_.erase(order_.back().first);
      order_.pop_back();
    }
  }

 private:
  std::mutex mu_;
  std::list<std::pair<std::string, Answer>> order_;
  std::map<std::string, std::list<std::pair<std::string, Answer>>::iterator, std::less<>> index_;
};

SelectionMemo& selection_memo() {
  static SelectionMemo memo;
  return memo;
}

}  // namespace

uint64_t pilots_run() { return g_pilots_run.load(); }

AutoSelection select_estimator_remembered(const std::string& key, const IntegrationProblem& problem,
                                          const StopRule& stop, PilotLatticeRules* rules) {
  if (auto hit = selection_memo().find(key)) {
    if (rules && hit->chosen_rule) rules->insert(std::move(*hit->chosen_rule));
    return std::move(hit->selection);
  }
  PilotLatticeRules built;
  SelectionMemo::Answer a;
  a.selection = select_estimator(problem, stop, &built);
  const AutoCandidate& w = a.selection.candidates[a.selection.chosen];
  if (w.estimator == "lattice") {
    if (auto it = built.find(static_cast<uint32_t>(w.points)); it != built.end()) a.chosen_rule = *it;
  }
  selection_memo().put(key, a);
  if (rules) rules->merge(built);
  return std::move(a.selection);
}

AutoSelection select_estimator(const IntegrationProblem& problem, const StopRule& stop, PilotLatticeRules* built) {
  g_pilots_run.fetch_add(1);
  IntegrationProblem pp = problem;
  pp.seed = mix64(problem.seed ^ 0x61757430706c6f74ULL);  // the pilot's own stream ("auto0plot")
  pp.covariance = false;  // the pilot needs each component's spread, not the pairs'
  const uint32_t U = problem.domain->uniforms();
  const size_t m = problem.integrand->components();
  AutoSelection sel;
  sel.components = m;

  // Per component, the mean of the run with the smallest standard error so far (the
  // relative targets are taken against it).
  std::vector<double> best_mean(m, 0.0), best_se(m, kInf);
  const auto keep_best = [&](const PilotRun& r, uint64_t samples) {
    for (size_t j = 0; j < m; ++j) {
      const double se = r.sd[j] / std::sqrt(static_cast<double>(samples));
      if (std::isfinite(se) && se < best_se[j]) {
        best_se[j] = se;
        best_mean[j] = r.mean[j];
      }
    }
  };

  // Uniform: the sd of one point. A vector integrand's runs on a one-point scrambled
  // Sobol' set (a uniform point; the uniform kernel keeps component 0 only).
  std::vector<Pilot> pilots(1);
  {
    const auto k = m == 1 ? make_uniform_kernel(pp) : make_qmc_kernel(pp, 1);
    const PilotRun u = pilot(*k, kPilotUniformPoints, 1, m);
    sel.pilot_evaluations += u.evaluations;
    pilots[0].points = {1};
    pilots[0].sd = {u.sd};
    keep_best(u, kPilotUniformPoints);
    AutoCandidate uni;
    uni.estimator = "uniform";
    sel.candidates.push_back(uni);
  }

  // Randomized QMC: 8 randomizations at each pilot size. Lattice rules are built once per
  // size and shared by both periodizations.
  const std::vector<double> weights(U, kDefaultLatticeWeight);
  PilotLatticeRules own_rules;
  PilotLatticeRules& rules = built ? *built : own_rules;
  const auto run_at = [&](size_t i, uint64_t want) {
    const AutoCandidate& c = sel.candidates[i];
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
    const PilotRun r = pilot(*k, kPilotShifts, points, m);
    sel.pilot_evaluations += r.evaluations;
    pilots[i].points.push_back(points);
    pilots[i].sd.push_back(r.sd);
    keep_best(r, kPilotShifts);
  };
  const std::vector<std::pair<std::string, std::string>> rqmc = {{"qmc", ""}, {"lattice", "baker"}, {"lattice", "none"}};
  for (const auto& [name, periodize] : rqmc) {
    AutoCandidate c;
    c.estimator = name;
    c.periodize = periodize;
    sel.candidates.push_back(c);
    pilots.emplace_back();
    run_at(sel.candidates.size() - 1, kSmall);
    run_at(sel.candidates.size() - 1, kLarge);
  }

  // Each component's target half-width: the looser of its two (it meets when either is
  // met); with neither, 1e-4 relative (or absolute, for an integral of 0).
  std::vector<double> eps(m, 0.0);
  for (size_t j = 0; j < m; ++j) {
    const double abs_target = component_abs_target(stop, j), rel_target = component_rel_target(stop, j);
    double e = abs_target > 0.0 ? abs_target : 0.0;
    if (rel_target > 0.0) e = std::max(e, rel_target * std::fabs(best_mean[j]));
    if (!(e > 0.0)) e = 1e-4 * std::fabs(best_mean[j]);
    if (!(e > 0.0)) e = 1e-4;
    eps[j] = e;
  }
  const double t = critical_value(stop.confidence, kMinRandomizations);
  for (size_t i = 0; i < sel.candidates.size(); ++i) predict(sel.candidates[i], pilots[i], eps, U, t);

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
      for (size_t i = 1; i < sel.candidates.size(); ++i) {
        if (!std::isfinite(sel.candidates[i].predicted_evaluations)) continue;
        run_at(i, third);
        predict(sel.candidates[i], pilots[i], eps, U, t);
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
  sel.target_half_width = eps[w.limiting_component];
  const std::string whose =
      m == 1 ? "its" : fmt::format("component {}'s (the one that needs the most randomizations)", w.limiting_component);
  sel.reason = fmt::format(
      "{} with {} points per sample: {} pilot spread falls as evaluations^-{:.2f}, so it needs about {} "
      "evaluations to reach +-{:.3g} at {:g}%, against {}; pilot: {} evaluations",
      label, w.points, whose, w.rate, count_text(w.predicted_evaluations), sel.target_half_width,
      100.0 * stop.confidence, others, sel.pilot_evaluations);
  return sel;
}

}  // namespace tally
