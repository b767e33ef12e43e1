#pragma once
// The one forecast of "how many samples and seconds until each rule fires", from
// the current σ and throughput. JobRunner::prediction / eta_seconds (status, ETA)
// and the validate pilot all read it. Pure function, thread-safe.
#include <cstdint>
#include <optional>

#include "common/engine/kernel.hpp"
#include "common/engine/limits.hpp"
#include "common/engine/stop_rule.hpp"

namespace tally {

struct RuleForecast {
  double samples = 0.0;  // total samples when the rule fires
  double seconds = 0.0;  // seconds from now until it fires
};

struct Forecast {
  double samples_needed = 0.0;               // the error target's need from σ (before min_samples)
  std::optional<RuleForecast> error_target;  // set when the rule has a target and σ is known
  std::optional<RuleForecast> max_samples;   // set when the rule has max_samples and rate > 0
  std::optional<RuleForecast> time_budget;   // set when the rule has a budget
  std::optional<RuleForecast> job_cap;       // the caps; set when rate > 0
  // The earliest of error_target, max_samples and time_budget (the rule itself),
  // in seconds; +inf when none can be forecast.
  double rule_seconds() const;
};

// `done`/`compute_seconds`: samples and seconds so far; `rate`: samples per second
// from now on. The error target needs ≥ 2 samples' worth of σ in `err`.
Forecast forecast(const StopRule& rule, const JobCaps& caps, const ErrorSummary& err, uint64_t done,
                  double compute_seconds, double rate);

}  // namespace tally
