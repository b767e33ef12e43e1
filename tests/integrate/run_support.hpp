#pragma once
// Runs a job spec through the production path: compile_job -> JobRunner -> run_local.
#include <memory>
#include <nlohmann/json.hpp>

#include "common/engine/local_executor.hpp"
#include "common/integrate/integration_counters.hpp"
#include "common/jobs/job_factory.hpp"
#include "common/protocol/kind_json.hpp"

namespace tally::testing {

struct Ran {
  std::unique_ptr<JobDefinition> job;
  std::unique_ptr<JobRunner> runner;
  const JobRunner* operator->() const { return runner.get(); }
};

inline Ran run_spec(const nlohmann::json& spec, unsigned threads = 1) {
  Ran r;
  r.job = compile_job(spec, JobLimits{});
  r.runner = std::make_unique<JobRunner>(r.job->kernel(), r.job->stop_rule(), JobCaps{});
  run_local(*r.runner, threads);
  return r;
}

}  // namespace tally::testing
