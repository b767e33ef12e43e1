#pragma once
// One job as the server holds it: the immutable submission, its event log and
// its mutable state. The state is private: only the manager (lifecycle) and the
// recorder (persistence, recovery) touch it, under the job's lock. Everyone else
// reads a JobSnapshot (JobManager::snapshot) and never locks a job.
#include <atomic>
#include <chrono>
#include <cstdint>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <string>

#include "common/engine/job_definition.hpp"
#include "common/engine/job_runner.hpp"
#include "common/protocol/job_snapshot.hpp"
#include "server/jobs/event_log.hpp"

namespace tally {

// What a finished job's documents show, built from its runner without the job's lock
// (each part is a pass over every pixel of an image): JobManager::finish_locked.
struct FinishViews {
  std::shared_ptr<const nlohmann::json> final_result;  // engine_json
  std::shared_ptr<const RunFacts> facts;              // run_facts
  std::shared_ptr<const std::string> progress;        // the last progress event's data (watchers' snapshot)
};

// What a job's end sets (JobManager::finish_locked), worked out before it is published:
// a job that ends at a pass boundary is stored with it first (JobRecorder::take), and
// reads as finished only once that save is done.
struct JobEnding {
  JobStatus status = JobStatus::failed;
  std::string error;
  double finished_at = 0;
  std::shared_ptr<const nlohmann::json> final_result;
  std::shared_ptr<const RunFacts> facts;
};

class Job : public std::enable_shared_from_this<Job> {
 public:
  Job(std::string id, int64_t seq, nlohmann::json spec, int priority, double created_at, uint64_t epoch,
      size_t event_buffer, std::string owner = {})
      : id_(std::move(id)), seq_(seq), spec_(std::make_shared<const nlohmann::json>(std::move(spec))),
        priority_(priority), created_at_(created_at), owner_(std::move(owner)), events_(epoch, event_buffer) {}

  const std::string& id() const { return id_; }
  int64_t seq() const { return seq_; }
  const nlohmann::json& spec() const { return *spec_; }
  int priority() const { return priority_; }
  // The principal that submitted it ("" without access control).
  const std::string& owner() const { return owner_; }
  double created_at() const { return created_at_; }
  // Thread-safe by itself (its own lock); the event streams read it.
  EventLog& events() const { return events_; }

 private:
  friend class JobManager;
  friend class JobRecorder;

  // The picture routes read; call under mu_. `with_runner`: also a copy of the runner
  // (else one is made only when the views built at the pass boundary are missing).
  JobSnapshot snapshot_locked(bool with_runner) const;

  const std::string id_;
  const int64_t seq_;
  const std::shared_ptr<const nlohmann::json> spec_;
  const int priority_;
  const double created_at_;
  const std::string owner_;
  mutable EventLog events_;
  // The owner's running-jobs quota at submission; guarded by the manager's mutex.
  uint64_t owner_max_running_ = UINT64_MAX;
  // Memory the job's state takes while it is in memory (JobManager::state_bytes), and
  // whether it is counted against the budget now; guarded by the manager's mutex.
  uint64_t state_bytes_ = 0;
  bool charged_ = false;
  // Bytes of the job's row in the store (spec, result, checkpoint), for retention.
  std::atomic<uint64_t> stored_bytes_{0};

  mutable std::mutex mu_;
  // --- guarded by mu_ ---
  std::shared_ptr<const JobDefinition> def_;  // null if the stored spec no longer compiles
  // The channel state, in memory only while the job runs (and for queued jobs resumed
  // from a checkpoint or extended): null before it starts, once finished and stored,
  // or if it could not be restored. facts_ then says what the views show.
  std::unique_ptr<JobRunner> runner_;
  std::shared_ptr<const RunFacts> facts_;
  JobCaps caps_;  // the runner's caps, fixed at submission
  JobStatus status_ = JobStatus::queued;
  std::string error_;
  double started_at_ = 0, finished_at_ = 0;
  std::shared_ptr<const nlohmann::json> final_result_;  // engine part of a finished job's status (also stored)
  uint64_t version_ = 1;  // bumped on every change: keys snapshots, the status cache and saves
  mutable std::shared_ptr<const JobRunner> published_;  // copy of runner_ at published_version_
  mutable uint64_t published_version_ = 0;
  // The data of a watcher snapshot's progress event, built once per version off
  // the I/O threads (on_pass_done, finish) and shared by every watcher.
  mutable std::shared_ptr<const std::string> watch_progress_;
  mutable uint64_t watch_progress_version_ = 0;
  // A committed pass whose progress event is not yet in the log (on_pass_done builds it
  // without the lock): a snapshot then shows the last published progress, or none, and
  // the new one follows live — never the same pass twice.
  bool publishing_ = false;
  // engine_json at engine_version_ for a running job's status, built at the pass
  // boundary on the worker thread (a status GET then does no pass over every pixel).
  std::shared_ptr<const nlohmann::json> engine_;
  uint64_t engine_version_ = 0;
  // The runner's figures the documents show (live_run_facts), built with engine_: a
  // snapshot for the views then copies no runner (it takes the rule from the runner,
  // since extend changes it between passes).
  std::shared_ptr<const RunFacts> live_facts_;
  std::chrono::steady_clock::time_point last_checkpoint_{};
  bool cancel_requested_ = false;
  // Its last pass is merged and its ending is being stored (JobManager::on_pass_done):
  // it still reads as running, and nothing else may end it.
  bool finishing_ = false;

  // Serialises store writes of this job; a save older than the last one is skipped.
  std::mutex save_mu_;
  uint64_t saved_version_ = 0;     // guarded by save_mu_
  // Set (under save_mu_) once DELETE removed the job's row: a save still in flight for
  // it (a retry of a failed final save, which runs after the job reads as finished)
  // must not write the row back.
  bool removed_ = false;
  uint64_t checkpoint_bytes_ = 0;  // guarded by save_mu_: size of the stored checkpoint
};

}  // namespace tally
