#pragma once
// {"kind": "lighting", ...} job specs: parse, plan, build the Embree scene and the
// kernel (point queries or an image). Format and rules in docs/lighting.md.
#include <memory>
#include <nlohmann/json.hpp>

#include "common/engine/job_definition.hpp"

namespace tally {

// Throws SpecError (with the JSON pointer of the bad field) for bad specs and
// std::runtime_error when Embree fails to build the scene.
std::unique_ptr<JobDefinition> compile_lighting_job(const nlohmann::json& spec, const JobLimits& limits);

}  // namespace tally
