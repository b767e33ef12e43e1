#pragma once
// JSON views of a lighting job's typed plan and result (docs/lighting.md), and its
// stored specs read as an older engine did.
#include <nlohmann/json.hpp>

#include "common/lighting/lighting_plan.hpp"

namespace tally {

nlohmann::json lighting_plan_json(const LightingPlan& plan);
nlohmann::json lighting_result_json(const LightingResult& result);
// A stored lighting spec as the engine of `results_version` read it (spec_as_of,
// job_kinds.hpp): versions 0-4 read a sobol image spec without "replicates" as 8
// replicates (5 made it 4 for images; point queries keep 8).
nlohmann::json lighting_spec_as_of(nlohmann::json spec, uint32_t results_version);

}  // namespace tally
