#pragma once
// The running statistics of a job as JSON: the same fields in the CLI's --json
// output, the server's GET /v1/jobs/{id}, progress events and the study.
#include <nlohmann/json.hpp>

#include "common/engine/job_definition.hpp"
#include "common/engine/job_runner.hpp"

namespace tally {

// The non-zero counters by the names the job's kernel declared.
nlohmann::json counters_json(const JobState& state);
// Compact: what a progress event carries.
nlohmann::json progress_json(const JobRunner& runner);
// Everything: progress + diagnostics + counters + trace + cost curve + kind result.
nlohmann::json result_json(const JobRunner& runner, const JobDefinition& job);

}  // namespace tally
