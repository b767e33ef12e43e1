#pragma once
// The job lifecycle state machine: admission (running set + bounded queue),
// the executor's pass callbacks (commit, events), cancel/extend, shutdown, and
// the snapshots routes read. Persistence and recovery are the recorder's
// (job_recorder.hpp); JSON views are the protocol layer's (job_json.hpp). Knows
// nothing about HTTP: failures are JobError, mapped to statuses by the routes.
#include <condition_variable>
#include <list>
#include <map>
#include <stop_token>
#include <thread>
#include <memory>
#include <mutex>
#include <optional>
#include <nlohmann/json.hpp>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "common/engine/job_definition.hpp"
#include "common/protocol/job_snapshot.hpp"
#include "server/executor/executor.hpp"
#include "server/jobs/job.hpp"
#include "server/jobs/job_recorder.hpp"
#include "server/jobs/job_store.hpp"

namespace tally {

class JobError : public std::runtime_error {
 public:
  enum class Kind { not_found, conflict, queue_full, unavailable, quota };
  JobError(Kind kind, const std::string& what) : std::runtime_error(what), kind_(kind) {}
  Kind kind() const noexcept { return kind_; }

 private:
  Kind kind_;
};

struct ManagerConfig {
  unsigned workers = 1;
  JobLimits limits;          // per-job limits and caps (the one set: common/engine/limits.hpp)
  size_t max_running = 16;   // jobs sharing the workers at once
  size_t max_queued = 256;   // jobs waiting for a running slot
  double checkpoint_interval_s = 0.5;
  size_t event_buffer = 1024;
  double chunk_target_s = 0.004;
  // Memory for jobs' state (JobManager::state_bytes): a job that needs more is refused
  // (SpecError naming the field that makes it big); jobs start only while their state
  // fits beside the others in memory. 0: no budget.
  uint64_t memory_budget = 0;
  // Decoded states of finished jobs kept for their image routes (LRU).
  uint64_t finished_cache_bytes = 256ULL << 20;
  // Finished jobs are deleted, oldest first, beyond any of these (0: no limit); applied
  // at recover() and every retention_interval_s.
  double retain_max_age_s = 0;
  size_t retain_max_jobs = 0;
  uint64_t retain_max_bytes = 0;
  double retention_interval_s = 60;
  // Builds the executor (e.g. cluster mode's RedisExecutor); unset: the in-process
  // worker pool with `workers` threads.
  std::function<std::unique_ptr<Executor>(ExecutorCallbacks)> make_executor;
};

// Who submits a job and within which limits. The default is the anonymous owner
// with the server's own limits (no access control).
struct Submitter {
  std::string owner;
  uint64_t max_running = UINT64_MAX;  // the owner's jobs computing at once; more wait in the queue
  uint64_t max_queued = UINT64_MAX;   // the owner's jobs waiting; beyond: JobError quota
  std::optional<JobLimits> limits;    // per-job limits and caps; nullopt: the server's
};

struct ManagerStats {
  std::map<std::string, size_t> jobs_by_state;
  size_t queue_depth = 0;
  double samples_per_second = 0;  // sum over running jobs
  uint64_t samples_total = 0;     // computed by the workers since start
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
};

class JobManager {
 public:
  JobManager(ManagerConfig config, JobStore& store, JobCompiler compiler);
  ~JobManager();

  // Loads the store: finished jobs are served as stored, unfinished ones resume
  // from their last checkpoint. Call once, before serving.
  void recover();

  // SpecError naming the field that makes the job big if its state could never fit
  // the memory budget (`def` compiled from `spec` with `limits`).
  void check_memory(const nlohmann::json& spec, const JobLimits& limits, const JobDefinition& def) const;
  // Throws SpecError (invalid spec) or JobError (queue full, shutting down).
  std::shared_ptr<Job> submit(const nlohmann::json& spec, int priority = 0, const Submitter& who = {});
  std::shared_ptr<Job> find(const std::string& id) const;  // null if unknown
  std::vector<std::shared_ptr<Job>> list() const;           // in submission order
  // The job as it is now, taken under its lock (JobError not_found if unknown).
  // `views` (what the status and list documents need): the runner's figures come from
  // the views built at its last pass boundary, and no runner is copied: a running
  // image's state can be hundreds of MB, and this runs on I/O threads. `state` also
  // gives JobSnapshot::runner (a copy made once per version) while it is in memory:
  // the image routes read its channels.
  enum class SnapshotOf { views, state };
  JobSnapshot snapshot(const std::string& id, SnapshotOf of = SnapshotOf::views) const;
  JobSnapshot snapshot(const Job& job, SnapshotOf of = SnapshotOf::views) const;
  std::vector<JobSnapshot> snapshots() const;  // every job, in submission order (views)
  // What a new or lagging watcher starts with: state, progress (once a pass ran)
  // and end (finished), all with the id of the log's last event. Cheap: copies no
  // runner; the progress part is built once per job version by the pass-done and
  // finish paths (worker threads) and shared by every watcher.
  std::vector<Event> watch_snapshot(const Job& job) const;
  JobStatus status(const Job& job) const;
  // Queued: cancelled at once; running: at the next chunk boundary. JobError on
  // unknown id (not_found) or a finished job (conflict).
  std::shared_ptr<Job> cancel(const std::string& id);
  // Reopens a finished job with a new rule. JobError: not_found, conflict.
  std::shared_ptr<Job> extend(const std::string& id, const StopRule& rule);

  // Deletes a finished job from memory and the store. JobError: not_found, conflict
  // (still queued or running: cancel it first).
  void remove(const std::string& id);
  // Deletes finished jobs beyond the retention limits (oldest finished first); returns
  // their ids. Queued and running jobs are never touched.
  std::vector<std::string> apply_retention();
  // The job's channel state: the runner's while it is in memory, else read back from
  // the store's checkpoint (finished jobs; cached, bounded). Null if not available.
  // May read the disk: call it off the I/O threads.
  std::shared_ptr<const JobState> state(const JobSnapshot& s);
  // Bytes a job's state takes in memory: its channels and partitions, twice (the
  // runner's and the copy published to readers at each pass boundary).
  static uint64_t state_bytes(const JobDefinition& def);

  // Stop computing, checkpoint every unfinished job, end every event stream.
  void shutdown();
  bool shutting_down() const;
  // Why the server should not be called ready (the store is failing), else nullopt.
  std::optional<std::string> not_ready_reason() const;
  // Serving, but the operator should know: the store was salvaged at start.
  std::optional<std::string> ready_warning() const { return recorder_.store_damage(); }
  ManagerStats stats() const;
  const ManagerConfig& config() const { return config_; }
  const JobCompiler& compiler() const { return compiler_; }
  uint64_t epoch() const { return epoch_; }
  // Why the executor cannot compute (e.g. Redis unreachable), for /readyz.
  std::optional<std::string> executor_not_ready() const { return executor_->not_ready_reason(); }

 private:
  PassWork on_pass_done(const std::string& id, const PassWork& done, std::vector<BlockResult>&& results,
                        double wall);
  void on_failed(const std::string& id, const std::string& error);
  void on_cancelled(const std::string& id);
  void start_queued_locked();
  void job_left_scheduler(const Job& job);
  // Under job.mu_: marks the job finished from its runner (or `status` for a job that
  // never started), keeps its facts, publishes state + end.
  // Ends the job. `views`: its last views, built without the lock (on_pass_done); null:
  // built here (a cancel or failure, whose runner has not changed since its last pass).
  void finish_locked(Job& job, double now, std::optional<JobStatus> status = std::nullopt,
                     const FinishViews* views = nullptr);
  // finish_locked in two steps: what the end sets (built, not applied), then applying it
  // (with its events). on_pass_done stores the ending between the two.
  static JobEnding ending_locked(const Job& job, double now, std::optional<JobStatus> status,
                                 const FinishViews* views);
  void end_locked(Job& job, const JobEnding& ending, const FinishViews* views);
  void publish_state_locked(Job& job);
  // Under job.mu_: the progress event data for the job's current version.
  static std::shared_ptr<const std::string> watch_progress_locked(const Job& job);
  // Once a finished job is stored with its final checkpoint: frees its state.
  void release_state(Job& job);
  // Under mu_: picks the next job to start, or null (memory budget, quotas).
  std::shared_ptr<Job> next_to_start_locked();
  void retention_loop(std::stop_token st);
  std::shared_ptr<const JobState> load_finished_state(const JobSnapshot& s);

  ManagerConfig config_;
  JobCompiler compiler_;
  JobRecorder recorder_;
  uint64_t epoch_ = 1;

  mutable std::mutex mu_;
  std::map<std::string, std::shared_ptr<Job>> jobs_;
  std::vector<std::shared_ptr<Job>> order_;   // submission order
  std::vector<std::shared_ptr<Job>> queue_;   // waiting to run
  size_t running_ = 0;
  std::map<std::string, uint64_t> running_by_owner_;
  int64_t next_seq_ = 1;
  bool shutting_down_ = false;
  uint64_t memory_used_ = 0;   // sum of state_bytes_ of charged jobs
  uint64_t jobs_removed_ = 0;

  JobStore& store_;
  // Decoded finished states (LRU, at most config_.finished_cache_bytes).
  struct CachedState {
    std::string id;
    uint64_t version;
    std::shared_ptr<const JobState> state;
    uint64_t bytes;
  };
  mutable std::mutex cache_mu_;
  std::list<CachedState> cache_;  // most recent first
  uint64_t cache_bytes_ = 0;
  uint64_t state_loads_ = 0;

  std::mutex retention_mu_;
  std::condition_variable_any retention_cv_;
  std::jthread retention_;  // runs retention_loop when a limit is set

  std::unique_ptr<Executor> executor_;  // last: its workers call back into us
};

double unix_now();

}  // namespace tally
