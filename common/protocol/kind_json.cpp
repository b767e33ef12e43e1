#include "common/protocol/kind_json.hpp"

#include "common/integrate/integration_job.hpp"
#include "common/lighting/lighting_job.hpp"
#include "common/protocol/integration_json.hpp"
#include "common/protocol/lighting_json.hpp"

namespace tally {

using nlohmann::json;

json plan_json(const JobDefinition& job) {
  if (const auto* j = dynamic_cast<const IntegrationJob*>(&job)) return integration_plan_json(j->plan());
  if (const auto* j = dynamic_cast<const LightingJob*>(&job)) return lighting_plan_json(j->plan());
  return {{"kind", std::string(job.kind())}};
}

json kind_result_json(const JobDefinition& job, const JobRunner& runner) {
  if (const auto* j = dynamic_cast<const IntegrationJob*>(&job)) return integration_result_json(j->result(runner));
  if (const auto* j = dynamic_cast<const LightingJob*>(&job)) return lighting_result_json(j->result(runner));
  return json::object();
}

}  // namespace tally
