#pragma once
// Reads a `kind: integrate` job spec (JSON, format in docs/jobs.md) into an
// IntegrationJob; every error names its JSON pointer (SpecError). One of the few
// files of the job kinds that speak JSON: the spec readers.
#include <memory>
#include <nlohmann/json.hpp>

#include "common/engine/limits.hpp"
#include "common/integrate/integration_job.hpp"

namespace tally {

std::unique_ptr<IntegrationJob> compile_integration_job(const nlohmann::json& spec, const JobLimits& limits);

}  // namespace tally
