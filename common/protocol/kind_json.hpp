#pragma once
// The kind-specific parts of a job's documents: its plan (status, validate, `tally
// run --json`) and its result fields. Each job kind keeps them as typed structs
// (IntegrationJob::plan(), LightingJob::result() ...); this is the one place that
// knows every kind's views. A kind it does not know (e.g. a test's fake job) shows
// {"kind": ...} as its plan and an empty result.
#include <nlohmann/json.hpp>

#include "common/engine/job_definition.hpp"
#include "common/engine/job_runner.hpp"

namespace tally {

nlohmann::json plan_json(const JobDefinition& job);
nlohmann::json kind_result_json(const JobDefinition& job, const JobRunner& runner);

}  // namespace tally
