#pragma once
// The short pilot run behind POST /v1/jobs/validate: a few passes on a throwaway
// runner, then n = (z sigma / eps)^2 from the pilot's sigma and throughput.
#include <nlohmann/json.hpp>

#include "common/engine/job_definition.hpp"

namespace tally {

struct PilotOptions {
  double seconds = 0.3;  // no new pass starts after this; a pass is cut at 4x
  unsigned threads = 1;
  unsigned parallelism = 1;  // workers the real job will get: predicted seconds scale by 1/this
  JobCaps caps;
};

// {"pilot": {...}, "prediction": {...}}; never throws for a compiled job.
nlohmann::json run_pilot(const JobDefinition& job, const PilotOptions& options);

}  // namespace tally
