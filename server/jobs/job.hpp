#pragma once
// One job as the server holds it: the immutable submission, the compiled
// definition, the runner (guarded by `mu`), its lifecycle state and event log.
#include <chrono>
#include <cstdint>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <string_view>

#include "common/engine/job_definition.hpp"
#include "common/engine/job_runner.hpp"
#include "server/jobs/event_log.hpp"

namespace tally {

enum class JobStatus { queued, running, succeeded, failed, cancelled };

std::string_view job_status_name(JobStatus s);
std::optional<JobStatus> parse_job_status(std::string_view s);
inline bool is_terminal(JobStatus s) { return s != JobStatus::queued && s != JobStatus::running; }

class Job {
 public:
  Job(std::string id_, int64_t seq_, nlohmann::json spec_, int priority_, double created_at_, uint64_t epoch,
      size_t event_buffer)
      : id(std::move(id_)), seq(seq_), spec(std::move(spec_)), priority(priority_), created_at(created_at_),
        events(epoch, event_buffer) {}

  const std::string id;
  const int64_t seq;
  const nlohmann::json spec;
  const int priority;
  const double created_at;
  EventLog events;

  mutable std::mutex mu;
  // --- guarded by mu ---
  std::shared_ptr<const JobDefinition> def;  // null if the stored spec no longer compiles
  std::unique_ptr<JobRunner> runner;         // null if it could not be restored
  JobStatus status = JobStatus::queued;
  std::string error;
  double started_at = 0, finished_at = 0;
  nlohmann::json final_result;  // engine part of a finished job's status (also stored)
  uint64_t version = 1;         // bumped on every change: keys the status cache and saves
  uint64_t cached_version = 0;
  std::string cached_status;
  std::chrono::steady_clock::time_point cached_at{};
  std::chrono::steady_clock::time_point last_checkpoint{};
  bool cancel_requested = false;

  // Serialises store writes of this job; a save older than the last one is skipped.
  std::mutex save_mu;
  uint64_t saved_version = 0;  // guarded by save_mu
};

}  // namespace tally
