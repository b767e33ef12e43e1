#pragma once
// JSON views of an integration job's typed plan and result (docs/jobs.md).
#include <nlohmann/json.hpp>

#include "common/integrate/integration_plan.hpp"

namespace tally {

nlohmann::json integrand_json(const IntegrandInfo& info);
nlohmann::json domain_json(const DomainInfo& info);
nlohmann::json estimator_plan_json(const EstimatorPlan& plan);
nlohmann::json integration_plan_json(const IntegrationPlan& plan);
nlohmann::json integration_result_json(const IntegrationResult& result);

}  // namespace tally
