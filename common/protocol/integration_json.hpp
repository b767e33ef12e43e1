#pragma once
// JSON views of an integration job's typed plan and result (docs/jobs.md).
#include <nlohmann/json.hpp>

#include "common/engine/job_runner.hpp"
#include "common/integrate/integration_job.hpp"
#include "common/integrate/integration_plan.hpp"

namespace tally {

nlohmann::json integrand_json(const IntegrandInfo& info);
nlohmann::json domain_json(const DomainInfo& info);
nlohmann::json estimator_plan_json(const EstimatorPlan& plan);
nlohmann::json integration_plan_json(const IntegrationPlan& plan);
nlohmann::json integration_result_json(const IntegrationResult& result);
nlohmann::json components_summary_json(const ComponentsSummary& summary);
// A progress event's fields of an integration job: {"components": summary} for a vector
// integrand (count, met, worst), else nothing.
nlohmann::json integration_progress_json(const IntegrationJob& job, const JobRunner& runner);

}  // namespace tally
