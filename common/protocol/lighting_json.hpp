#pragma once
// JSON views of a lighting job's typed plan and result (docs/lighting.md).
#include <nlohmann/json.hpp>

#include "common/lighting/lighting_plan.hpp"

namespace tally {

nlohmann::json lighting_plan_json(const LightingPlan& plan);
nlohmann::json lighting_result_json(const LightingResult& result);

}  // namespace tally
