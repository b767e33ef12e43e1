#pragma once
// A spec compiled once for a job, within the memory budget: the one compile an
// accepted submit (or validate) does.
#include <memory>
#include <nlohmann/json.hpp>

#include "common/engine/job_definition.hpp"
#include "server/jobs/admission.hpp"
#include "server/jobs/job_recorder.hpp"

namespace tally {

// The spec's definition, compiled once with `limits`, its max_state_bytes held to the
// memory budget. SpecError if the spec is invalid; if its state could never fit the
// budget (the error names the field that makes it big and says the budget is the
// limit); or if state and scene together are over it (Admission::over_budget).
std::unique_ptr<JobDefinition> compile_within_budget(const JobCompiler& compiler, const nlohmann::json& spec,
                                                     const JobLimits& limits, const Admission& admission);

}  // namespace tally
