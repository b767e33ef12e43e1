#pragma once
// An immutable picture of one job, taken by the manager under the job's lock
// (JobManager::snapshot). Views (job_json.hpp) and routes read it with no lock:
// the runner, definition and result it points to are never mutated after they
// are published.
#include <cstdint>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <string_view>

#include "common/engine/job_definition.hpp"
#include "common/engine/job_runner.hpp"

namespace tally {

enum class JobStatus { queued, running, succeeded, failed, cancelled };

std::string_view job_status_name(JobStatus s);
std::optional<JobStatus> parse_job_status(std::string_view s);
inline bool is_terminal(JobStatus s) { return s != JobStatus::queued && s != JobStatus::running; }

// What the executor says about a running job: cluster mode fills it (docs/cluster.md);
// the in-process executor leaves it empty, and the views then add nothing.
struct ExecutorNote {
  std::string waiting_reason;  // why the job makes no progress now ("": it does)
  bool held_queued = false;    // a running job nothing can compute yet (no worker in its pool): reads as queued
  bool has_blocks = false;     // the counts below are known
  uint64_t pending = 0, in_flight = 0, redelivered = 0;  // blocks of the current pass
};

// What the views show of a job whose channel state is not in memory: a queued job
// that has not started (its state is allocated when it starts) or a finished one
// (its state lives in the store's checkpoint and is read back for images only).
// Taken from the runner (run_facts, job_json.hpp) when its state is released, so the
// documents read the same as when the runner was there.
struct RunFacts {
  uint64_t samples = 0, passes = 0;
  std::optional<Estimate> headline;  // set once channel 0 has samples
  StopReason stop_reason = StopReason::none;
  bool target_met = false;
  StopRule rule;
  double compute_seconds = 0;
  std::string progress_event;  // data of the job's last `progress` event, "" before its first pass
  // The engine generation that computed the state (JobState::results_version); 0 for
  // facts stored before it was recorded.
  uint32_t results_version = 0;
};

struct JobSnapshot {
  std::string id;
  int64_t seq = 0;
  int priority = 0;
  std::string owner;  // the submitting principal ("" without access control)
  std::shared_ptr<const nlohmann::json> spec;  // as submitted
  double created_at = 0, started_at = 0, finished_at = 0;  // unix seconds, 0 = not yet
  JobStatus status = JobStatus::queued;
  std::string error;
  uint64_t version = 0;                          // bumped on every change of the job
  std::shared_ptr<const JobDefinition> def;      // null if the stored spec no longer compiles
  // At the last pass boundary; null if not in memory, or not asked for (a snapshot for
  // the views: JobManager::SnapshotOf).
  std::shared_ptr<const JobRunner> runner;
  std::shared_ptr<const RunFacts> facts;         // when runner is null: what it would show (null: unknown)
  std::shared_ptr<const nlohmann::json> final_result;  // engine part of a finished job's status
  // Engine part of a running job's status at `version`, built once per pass off the
  // I/O threads (null: build it from the runner).
  std::shared_ptr<const nlohmann::json> engine;
  uint64_t last_event_id = 0;                    // the job's event log at the same instant
  ExecutorNote executor;                         // running jobs in cluster mode
  std::string cached_from;  // answered from this finished job's stored result ("" : computed)
};

}  // namespace tally
