#pragma once
// The job lifecycle state machine: admission (running set + bounded queue),
// the executor's pass callbacks (commit, events), cancel/extend, shutdown, and
// the snapshots routes read. Persistence and recovery are the recorder's
// (job_recorder.hpp); JSON views are the protocol layer's (job_json.hpp). Knows
// nothing about HTTP: failures are JobError, mapped to statuses by the routes.
#include <map>
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
};

class JobManager {
 public:
  JobManager(ManagerConfig config, JobStore& store, JobCompiler compiler);
  ~JobManager();

  // Loads the store: finished jobs are served as stored, unfinished ones resume
  // from their last checkpoint. Call once, before serving.
  void recover();

  // Throws SpecError (invalid spec) or JobError (queue full, shutting down).
  std::shared_ptr<Job> submit(const nlohmann::json& spec, int priority = 0, const Submitter& who = {});
  std::shared_ptr<Job> find(const std::string& id) const;  // null if unknown
  std::vector<std::shared_ptr<Job>> list() const;           // in submission order
  // The job as it is now, taken under its lock (JobError not_found if unknown).
  JobSnapshot snapshot(const std::string& id) const;
  JobSnapshot snapshot(const Job& job) const;
  std::vector<JobSnapshot> snapshots() const;  // every job, in submission order
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
  // Under job.mu_: marks the job finished from its runner, publishes state + end.
  void finish_locked(Job& job, double now);
  void publish_state_locked(Job& job);
  // Under job.mu_: the progress event data for the job's current version.
  static std::shared_ptr<const std::string> watch_progress_locked(const Job& job);

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

  std::unique_ptr<Executor> executor_;  // last: its workers call back into us
};

double unix_now();

}  // namespace tally
