#include "common/protocol/status_json.hpp"

#include <cmath>

#include <algorithm>

#include "common/protocol/job_kinds.hpp"
#include "common/stats/tail_index.hpp"

namespace tally {

using nlohmann::json;

namespace {
json finite_or_null(double v) { return std::isfinite(v) ? json(v) : json(nullptr); }

// A counter by the name its kernel gave it; 0 when the kernel does not count it.
uint64_t counter(const JobState& s, std::string_view name) {
  const auto it = std::find(s.counter_names.begin(), s.counter_names.end(), name);
  return it == s.counter_names.end() ? 0 : s.counters[static_cast<size_t>(it - s.counter_names.begin())];
}
}  // namespace

json counters_json(const JobState& s) {
  json j = json::object();
  for (size_t i = 0; i < s.counter_names.size(); ++i) {
    if (s.counters[i] != 0) j[s.counter_names[i]] = s.counters[i];
  }
  return j;
}

json progress_json(const JobRunner& runner) {
  const JobState& s = runner.state();
  const Estimate e = runner.headline();
  const ErrorSummary err = runner.error();
  json j;
  j["passes"] = s.passes;
  j["samples"] = s.samples;
  j["compute_seconds"] = s.compute_seconds;
  j["samples_per_second"] = runner.samples_per_second();
  j["estimate"] = {{"mean", finite_or_null(e.mean)},
                   {"variance", finite_or_null(e.variance)},
                   {"std_error", finite_or_null(e.std_error)},
                   {"rel_error", finite_or_null(e.rel_error)},
                   {"ci", {finite_or_null(e.ci_lo), finite_or_null(e.ci_hi)}},
                   {"confidence", e.confidence},
                   {"n", e.n}};
  j["error"] = {{"abs", finite_or_null(err.abs_error)}, {"rel", finite_or_null(err.rel_error)}};
  j["stop_reason"] = std::string(stop_reason_name(runner.stop_reason()));
  j["target_met"] = runner.target_met();
  if (const auto p = runner.prediction()) {
    j["prediction"] = {{"samples_needed", finite_or_null(p->samples_needed)},
                       {"samples_remaining", finite_or_null(p->samples_remaining)},
                       {"seconds_remaining", finite_or_null(p->seconds_remaining)}};
  } else {
    j["prediction"] = nullptr;
  }
  return j;
}

json result_json(const JobRunner& runner, const JobDefinition& job) {
  const JobState& s = runner.state();
  json j = progress_json(runner);
  j["kind"] = std::string(job.kind());
  j["seed"] = job.seed();
  json curve = json::array();
  for (const CostPoint& c : runner.cost_curve({1e-2, 1e-3, 1e-4})) {
    curve.push_back({{"rel_error", c.rel_error},
                     {"samples", finite_or_null(c.samples)},
                     {"seconds", finite_or_null(c.seconds)}});
  }
  j["cost_curve"] = curve;
  json d;
  d["nonfinite"] = counter(s, "nonfinite");
  const auto alpha = runner.tail_alpha();
  d["tail_index"] = alpha ? finite_or_null(*alpha) : json(nullptr);
  d["heavy_tail"] = runner.heavy_tail();
  const uint64_t att = counter(s, "rejection_attempts");
  d["acceptance_rate"] =
      att > 0 ? json(static_cast<double>(counter(s, "rejection_accepts")) / static_cast<double>(att)) : json(nullptr);
  d["effective_sample_size"] = s.weights.empty() ? json(nullptr) : json(s.weights.ess());
  d["warnings"] = runner.warnings();
  j["diagnostics"] = d;
  j["counters"] = counters_json(s);
  json trace = json::array();
  for (const TracePoint& p : s.trace) {
    trace.push_back({p.time_s, p.samples, finite_or_null(p.mean), finite_or_null(p.std_error)});
  }
  j["trace"] = trace;
  if (runner.error_message()) j["error_message"] = *runner.error_message();
  j["result"] = kind_result_json(job, runner);
  return j;
}

}  // namespace tally
