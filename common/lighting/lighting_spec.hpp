#pragma once
// Reads a {"kind": "lighting", ...} job spec (JSON, format in docs/lighting.md): parse,
// plan, build the Embree scene and the kernel (point queries or an image). One of the
// few files of the job kinds that speak JSON: the spec readers (with scene_json.hpp).
#include <memory>
#include <nlohmann/json.hpp>

#include "common/engine/limits.hpp"
#include "common/lighting/lighting_job.hpp"

namespace tally {

// Throws SpecError (with the JSON pointer of the bad field) for bad specs and
// std::runtime_error when Embree fails to build the scene.
std::unique_ptr<LightingJob> compile_lighting_job(const nlohmann::json& spec, const JobLimits& limits);

}  // namespace tally
