#pragma once
// The "stop" object shared by every job kind:
//   {"max_samples": N, "time_budget_s": T, "abs_error": e, "rel_error": r,
//    "confidence": 0.95, "min_samples": 1000}
// At least one rule is required; whichever fires first stops the job.
#include "common/engine/job_definition.hpp"
#include "common/json/spec_reader.hpp"

namespace tally {

StopRule parse_stop_rule(SpecReader& stop, const JobLimits& limits);
nlohmann::json stop_rule_to_json(const StopRule& rule);

}  // namespace tally
