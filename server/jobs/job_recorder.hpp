#pragma once
// Persistence and recovery of jobs: what the manager saves at submission, at
// checkpoints and at the end, and how a restart turns stored rows back into jobs.
// Failures never take a job down silently: each is logged at warn with the job id
// and what it means for the job.
#include <condition_variable>
#include <functional>
#include <map>
#include <mutex>
#include <optional>
#include <stop_token>
#include <thread>
#include <memory>
#include <nlohmann/json.hpp>
#include <vector>

#include "common/engine/job_definition.hpp"
#include "server/jobs/job.hpp"
#include "server/jobs/job_store.hpp"
#include "server/jobs/store_health.hpp"

namespace tally {

using JobCompiler = std::function<std::unique_ptr<JobDefinition>(const nlohmann::json&, const JobLimits&)>;

class JobRecorder {
 public:
  JobRecorder(JobStore& store, JobCompiler compiler, JobLimits limits, size_t event_buffer);
  ~JobRecorder();

  // Saves the job's current state (with its checkpoint if asked). Thread-safe; an
  // older state never overwrites a newer one. Returns false if the store failed:
  // the failure is logged and counted, the store reported failing (store_problem)
  // and, if `retry`, the job is saved again every 200 ms until it is stored (with
  // its checkpoint while it is unfinished). The job runs on either way.
  bool persist(Job& job, bool with_checkpoint, bool retry = true);
  // The store's last error while its last save failed, else nullopt.
  std::optional<std::string> store_problem() const { return health_.problem(); }
  // What a salvage of a damaged store at open lost (JobStore::damage), else nullopt.
  std::optional<std::string> store_damage() const { return store_.damage(); }
  uint64_t store_failures() const { return health_.failures(); }

  struct Recovered {
    uint64_t epoch = 1;
    std::vector<std::shared_ptr<Job>> jobs;  // submission order; unfinished ones not yet queued
  };
  // Loads every stored job. Finished jobs come back as stored; unfinished ones
  // resume from their checkpoint, or are marked failed (and saved) if they cannot.
  Recovered recover();

 private:
  void retry_saves(std::stop_token st);

  JobStore& store_;
  JobCompiler compiler_;
  JobLimits limits_;
  size_t event_buffer_;
  StoreHealth health_;
  std::mutex retry_mu_;
  std::condition_variable_any retry_cv_;
  std::map<std::string, std::weak_ptr<Job>> retry_;  // saves that failed, by job id
  std::jthread retrier_;                              // last: runs retry_saves
};

}  // namespace tally
