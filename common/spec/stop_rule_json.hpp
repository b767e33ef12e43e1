#pragma once
// The "stop" object shared by every job kind:
//   {"max_samples": N, "time_budget_s": T, "abs_error": e, "rel_error": r,
//    "confidence": 0.95, "min_samples": 1000,
//    "component_targets": {"abs_error": [e0, null, ...], "rel_error": [r0, ...]}}
// At least one rule is required; whichever fires first stops the job. component_targets
// (a vector job's own target per component, null: the job-wide one) is checked here for
// its form; the integration spec checks its length against the integrand.
// The one reader of stop rules: a spec's "stop", a stored rule, and the body of
// POST /v1/jobs/{id}/extend (which passes `keep`: the job's rule, whose
// confidence and min_samples stay and may not be set by the body).
#include <nlohmann/json.hpp>

#include "common/engine/limits.hpp"
#include "common/engine/stop_rule.hpp"
#include "common/spec/spec_reader.hpp"

namespace tally {

StopRule parse_stop_rule(SpecReader& stop, const JobLimits& limits, const StopRule* keep = nullptr);
// A rule as stop_rule_to_json stored it (the job store's stop_rule column). The same
// reader, except that min_samples may be 1: a deterministic estimator's rule is
// "one pass decides" (min_samples 1), which a spec may not ask for (at least 2).
StopRule parse_stored_stop_rule(SpecReader& stop, const JobLimits& limits);
nlohmann::json stop_rule_to_json(const StopRule& rule);

}  // namespace tally
