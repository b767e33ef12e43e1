#pragma once
// `kind: integrate` jobs: spec parsing (every error names its JSON pointer) and the
// JobDefinition that runs them. The spec format is documented in docs/jobs.md.
#include <memory>
#include <nlohmann/json.hpp>

#include "common/engine/job_definition.hpp"

namespace tally {

std::unique_ptr<JobDefinition> compile_integration_job(const nlohmann::json& spec,
                                                       const JobLimits& limits);

}  // namespace tally
