#include "common/integrate/integration_job.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <fmt/format.h>

#include "common/engine/component_targets.hpp"
#include "common/integrate/integration_counters.hpp"
#include "common/integrate/vector_integrand.hpp"
#include "common/integrate/vegas.hpp"

namespace tally {

IntegrationJob::IntegrationJob(Setup s) : s_(std::move(s)) {
  plan_.integrand = s_.integrand->describe();
  plan_.domain = s_.domain->describe();
  plan_.estimator = s_.estimator;
  plan_.dimensions = s_.domain->dimensions();
  plan_.measure = s_.domain->measure();
  plan_.stop = s_.stop;
  plan_.seed = s_.seed;
}

ComponentsSummary summarize_components(const std::vector<ComponentEstimate>& comps, const StopRule& stop) {
  ComponentsSummary cs;
  cs.count = comps.size();
  if (stop.has_error_target()) cs.met = 0;
  double worst_score = -1.0;
  for (size_t c = 0; c < comps.size(); ++c) {
    const ComponentEstimate& e = comps[c];
    const double half = e.error_estimate ? std::fabs(*e.error_estimate) : 0.5 * (e.ci_hi - e.ci_lo);
    const double rel = e.mean != 0.0 ? half / std::fabs(e.mean) : std::numeric_limits<double>::infinity();
    double score = rel;  // no target: the largest relative half-width is the worst
    if (stop.has_error_target()) {
      score = component_target_ratio(stop, c, {half, e.mean});
      if (score <= 1.0) {
        ++*cs.met;
      } else if (cs.unmet.size() < ComponentsSummary::kMaxUnmetListed) {
        cs.unmet.push_back(c);
      }
    }
    if (std::isnan(score)) score = std::numeric_limits<double>::infinity();  // unknown reads as worst
    if (score > worst_score) {
      worst_score = score;
      cs.worst = c;
      cs.worst_half_width = half;
      cs.worst_rel_half_width = rel;
    }
  }
  return cs;
}

IntegrationResult IntegrationJob::result(const JobRunner& runner) const {
  IntegrationResult r;
  r.integrand = plan_.integrand;
  r.domain = plan_.domain;
  r.estimator = plan_.estimator;
  r.evaluations = runner.state().counters[IntegrationCounter::evaluations];
  r.sample_unit = s_.sweep ? "point set" : (s_.deterministic ? "rule" : "point");
  if (s_.deterministic) r.error_estimate = runner.error().abs_error;
  const auto rep = vegas_report(runner.state());
  const size_t m = s_.integrand->components();
  if (m > 1 && s_.deterministic) {
    // Cubature: each component's value and the rule's error estimate (channel m + c).
    const auto& ch = runner.state().channels;
    for (size_t c = 0; c < m; ++c) {
      const bool have = ch.size() == 2 * m && ch[c].n > 0;
      ComponentEstimate e;
      e.mean = have ? ch[c].mean : std::numeric_limits<double>::quiet_NaN();
      e.error_estimate = have ? ch[m + c].mean : std::numeric_limits<double>::quiet_NaN();
      r.components.push_back(e);
    }
  } else if (m > 1) {
    const bool combined = rep && s_.estimator.combine == "weighted";
    for (size_t c = 0; c < m; ++c) {
      Estimate e = runner.estimate(c);  // the pooled samples of component c
      if (combined) {  // VEGAS's weighted passes, as the stop rule sees them
        const double z = (e.ci_hi - e.ci_lo) / (2.0 * e.std_error);
        e.mean = rep->combined_mean[c];
        e.std_error = rep->combined_std_error[c] * rep->error_scale;
        e.ci_lo = e.mean - z * e.std_error;
        e.ci_hi = e.mean + z * e.std_error;
      }
      r.components.push_back({e.mean, e.std_error, e.ci_lo, e.ci_hi, std::nullopt});
    }
    if (runner.state().channels.size() >= m + m * (m - 1) / 2) {  // the job keeps the pair channels
      const std::vector<double> cov = component_mean_covariance(runner.state(), m);
      for (size_t a = 0; a < m; ++a) {
        r.covariance_of_means.emplace_back(cov.begin() + static_cast<std::ptrdiff_t>(a * m),
                                           cov.begin() + static_cast<std::ptrdiff_t>((a + 1) * m));
      }
    }
  }
  if (m > 1) r.components_summary = summarize_components(r.components, s_.stop);
  if (rep) {
    VegasSummary v;
    for (const VegasIteration& it : rep->iterations) {
      v.iterations.push_back({it.tally.n, it.tally.mean,
                              it.tally.n > 1 ? std::optional<double>(it.tally.std_error()) : std::nullopt, it.warmup});
    }
    v.used_iterations = rep->used;
    v.chi2_per_dof = rep->chi2_per_dof;
    v.p_value = rep->p_value;
    v.consistent = !rep->inconsistent;
    v.error_scale = rep->error_scale;
    if (rep->hypercubes > 0) {
      const auto [lo, hi] = std::minmax_element(rep->next_allocation.begin(), rep->next_allocation.end());
      v.strata_per_axis = rep->strata_per_axis;
      v.hypercubes = rep->hypercubes;
      v.next_allocation_min = *lo;
      v.next_allocation_max = *hi;
    }
    r.vegas = std::move(v);
  }
  if (s_.reference) {
    r.reference = *s_.reference;
    const Estimate e = runner.headline();  // channel 0, or VEGAS's combined passes
    r.error_vs_reference = e.mean - *s_.reference;
    if (e.std_error > 0 && std::isfinite(e.std_error)) r.z_score = (e.mean - *s_.reference) / e.std_error;
  }
  return r;
}

std::string IntegrationJob::summary_line(const JobRunner& runner) const {
  if (s_.deterministic) {
    const Estimate e = runner.headline();
    return fmt::format("{:.12g} ({}, error estimate {:.3g}, not a confidence interval)", e.mean, s_.estimator.type,
                       runner.error().abs_error);
  }
  if (s_.integrand->components() > 1) {  // the vector in one line: how many met, the worst one
    const IntegrationResult r = result(runner);
    const ComponentsSummary& cs = *r.components_summary;
    const ComponentEstimate& w = r.components[cs.worst];
    const std::string met = cs.met ? fmt::format(", {} meet the error target", *cs.met) : std::string();
    return fmt::format("{} components{}; worst: component {} = {:.10g} ± {:.3g} (relative half-width {:.3g})",
                       cs.count, met, cs.worst, w.mean, w.std_error, cs.worst_rel_half_width);
  }
  const Estimate e = runner.headline();  // channel 0, or VEGAS's combined passes
  return fmt::format("{:.10g} ± {:.3g} ({:g}% CI [{:.10g}, {:.10g}])", e.mean, e.std_error, 100.0 * e.confidence,
                     e.ci_lo, e.ci_hi);
}

}  // namespace tally
