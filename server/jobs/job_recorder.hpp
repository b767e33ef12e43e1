#pragma once
// Persistence and recovery of jobs: what the manager saves at submission, at
// checkpoints and at the end, and how a restart turns stored rows back into jobs.
// Failures never take a job down silently: each is logged at warn with the job id
// and what it means for the job.
#include <functional>
#include <memory>
#include <nlohmann/json.hpp>
#include <vector>

#include "common/engine/job_definition.hpp"
#include "server/jobs/job.hpp"
#include "server/jobs/job_store.hpp"

namespace tally {

using JobCompiler = std::function<std::unique_ptr<JobDefinition>(const nlohmann::json&, const JobLimits&)>;

class JobRecorder {
 public:
  JobRecorder(JobStore& store, JobCompiler compiler, JobLimits limits, size_t event_buffer)
      : store_(store), compiler_(std::move(compiler)), limits_(std::move(limits)), event_buffer_(event_buffer) {}

  // Saves the job's current state (with its checkpoint if asked). Thread-safe; an
  // older state never overwrites a newer one. A failed save is logged; the job runs on.
  void persist(Job& job, bool with_checkpoint);

  struct Recovered {
    uint64_t epoch = 1;
    std::vector<std::shared_ptr<Job>> jobs;  // submission order; unfinished ones not yet queued
  };
  // Loads every stored job. Finished jobs come back as stored; unfinished ones
  // resume from their checkpoint, or are marked failed (and saved) if they cannot.
  Recovered recover();

 private:
  JobStore& store_;
  JobCompiler compiler_;
  JobLimits limits_;
  size_t event_buffer_;
};

}  // namespace tally
