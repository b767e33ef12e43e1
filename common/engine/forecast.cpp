#include "common/engine/forecast.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "common/stats/confidence.hpp"

namespace tally {

namespace {
constexpr double kInf = std::numeric_limits<double>::infinity();
}

double Forecast::rule_seconds() const {
  double s = kInf;
  for (const auto* f : {&error_target, &max_samples, &time_budget}) {
    if (*f) s = std::min(s, (*f)->seconds);
  }
  return s;
}

Forecast forecast(const StopRule& rule, const JobCaps& caps, const ErrorSummary& err, uint64_t done,
                  double compute_seconds, double rate) {
  Forecast f;
  const double n = static_cast<double>(done);
  auto seconds_for = [&](double total) { return rate > 0 ? std::max(0.0, total - n) / rate : kInf; };
  f.samples_needed = kInf;
  // Per-component targets: the worst component's sigma says nothing about the others'
  // needs; the runner forecasts them from each component's own ratio (job_runner.cpp),
  // a pilot makes no error-target forecast for them.
  if (rule.has_error_target() && !rule.component_targets && std::isfinite(err.sigma)) {
    double need = kInf;
    if (rule.abs_error > 0) need = std::min(need, samples_for_half_width(err.sigma, rule.abs_error, rule.confidence));
    if (rule.rel_error > 0 && err.mean != 0.0) {
      need = std::min(need, samples_for_half_width(err.sigma, rule.rel_error * std::fabs(err.mean), rule.confidence));
    }
    f.samples_needed = need;
    // The rule cannot fire before min_samples.
    const double fires = std::max(need, static_cast<double>(rule.min_samples));
    f.error_target = RuleForecast{fires, seconds_for(fires)};
  }
  if (rule.max_samples > 0 && rate > 0) {
    const double m = static_cast<double>(rule.max_samples);
    f.max_samples = RuleForecast{m, seconds_for(m)};
  }
  if (rule.time_budget_s > 0) {
    const double left = std::max(0.0, rule.time_budget_s - compute_seconds);
    f.time_budget = RuleForecast{n + left * rate, left};
  }
  if (rate > 0) {
    const double cap_s = std::max(0.0, std::min(caps.max_seconds - compute_seconds,
                                                seconds_for(static_cast<double>(caps.max_samples))));
    f.job_cap = RuleForecast{n + cap_s * rate, cap_s};
  }
  return f;
}

}  // namespace tally
