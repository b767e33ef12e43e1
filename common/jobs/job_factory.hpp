#pragma once
// One entry point from a JSON job spec to a runnable job, for every job kind.
#include <memory>
#include <nlohmann/json.hpp>

#include "common/engine/job_definition.hpp"

namespace tally {

// Validates `spec` (throws SpecError with the JSON pointer of the first bad field)
// and compiles it. Dispatches on spec["kind"]: "integrate" | "lighting".
std::unique_ptr<JobDefinition> compile_job(const nlohmann::json& spec, const JobLimits& limits);

}  // namespace tally
