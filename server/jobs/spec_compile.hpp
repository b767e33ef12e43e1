#pragma once
// A spec compiled once for a job, within the memory budget: the one compile an
// accepted submit (or validate) does.
#include <memory>
#include <nlohmann/json.hpp>

#include "common/engine/job_definition.hpp"
#include "server/jobs/admission.hpp"
#include "server/jobs/job_recorder.hpp"

namespace tally {

// The spec's definition, compiled with `limits`. SpecError if the spec is invalid, or if
// its state could never fit the memory budget (Admission::over_budget): then the error
// names the field that makes it big, found by compiling again with the channels the
// budget allows (a refusal only).
std::unique_ptr<JobDefinition> compile_within_budget(const JobCompiler& compiler, const nlohmann::json& spec,
                                                     const JobLimits& limits, const Admission& admission);

}  // namespace tally
