#pragma once
// The job manager's figures for /metrics (JobManager::stats), and the part read off
// the jobs themselves: counts by state, throughput and the forecasts of work left.
#include <cstdint>
#include <map>
#include <memory>
#include <string>
#include <vector>

namespace tally {

class Job;

struct ManagerStats {
  std::map<std::string, size_t> jobs_by_state;
  size_t queue_depth = 0;
  double samples_per_second = 0;  // sum over running jobs
  uint64_t samples_total = 0;     // computed by the workers since start
  uint64_t groups_streamed = 0;   // result groups merged one by one as they came (streamed passes)
  unsigned workers = 0;
  unsigned busy_workers = 0;
  uint64_t store_failures = 0;  // failed saves since start
  bool store_ok = true;         // the last save succeeded
  std::map<std::string, double> cpu_seconds_by_owner;  // the executor's fair-share accounting
  uint64_t memory_budget = 0;        // 0: none
  uint64_t memory_used = 0;          // state of the jobs that hold it in memory
  uint64_t finished_cache_bytes = 0; // decoded finished states kept for image routes
  uint64_t state_loads = 0;          // finished jobs' states read back from the store
  uint64_t jobs_removed = 0;         // by DELETE or retention since start
  uint64_t preemptions = 0;          // jobs paused at a pass boundary for one that goes first
  uint64_t result_cache_hits = 0;    // submits answered from a finished job's stored result
  uint64_t result_cache_misses = 0;  // submits that looked and computed
  // Predicted CPU-seconds of work left (the jobs' own forecasts): running jobs from their
  // throughput and stop rule, queued ones from their pilot-free estimate (forecast_cpu_seconds).
  double predicted_cpu_seconds_running = 0;
  double predicted_cpu_seconds_queued = 0;
};

// Adds what the jobs say (each under its own lock): jobs_by_state (every state listed,
// 0 included), samples_per_second and the predicted CPU-seconds, a running job on its
// share of the executor's `workers`.
void add_job_figures(ManagerStats& s, const std::vector<std::shared_ptr<Job>>& jobs, unsigned workers);

}  // namespace tally
