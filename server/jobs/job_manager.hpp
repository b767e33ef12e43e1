#pragma once
// The job lifecycle state machine: admission (running set + bounded queue),
// the executor's pass callbacks (commit, events), cancel/extend, shutdown, and
// the snapshots routes read. Persistence and recovery are the recorder's
// (job_recorder.hpp); JSON views are the protocol layer's (job_json.hpp). Knows
// nothing about HTTP: failures are JobError, mapped to statuses by the routes.
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "common/engine/checkpoint.hpp"
#include "common/engine/job_definition.hpp"
#include "common/protocol/job_snapshot.hpp"
#include "server/executor/executor.hpp"
#include "server/jobs/admission.hpp"
#include "server/jobs/cached_answers.hpp"
#include "server/jobs/finished_state_cache.hpp"
#include "server/jobs/job.hpp"
#include "server/jobs/job_error.hpp"
#include "server/jobs/job_recorder.hpp"
#include "server/jobs/job_retention.hpp"
#include "server/jobs/preemption.hpp"
#include "server/jobs/spec_compile.hpp"
#include "server/jobs/job_store.hpp"
#include "server/jobs/manager_stats.hpp"

namespace tally {

struct ManagerConfig {
  unsigned workers = 1;
  JobLimits limits;          // per-job limits and caps (the one set: common/engine/limits.hpp)
  size_t max_running = 16;   // jobs sharing the workers at once
  size_t max_queued = 256;   // jobs waiting for a running slot
  double checkpoint_interval_s = 0.5;
  // States whose checkpoint is at most this many bytes are copied at the pass boundary
  // (JobRecorder::set_copy_bytes); bigger ones stream from the live state.
  uint64_t checkpoint_copy_bytes = kCheckpointPieceBytes;
  // Those bigger ones also have their passes streamed (ExecutorJob::stream_groups): the
  // executor hands results back group by group and each merges at once, so no pass's
  // results (twice an image's state) are held beside the state. Tests turn it off to
  // merge whole passes, as behind a cluster executor, which does not stream.
  bool stream_passes = true;
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
  // Preemption: a running job may be paused at a pass boundary for a waiting job of
  // higher priority (or of an owner below its fair share) once it has run this long
  // since it (re)started; negative: never.
  double preempt_min_run_s = 10;
  // Builds the executor (e.g. cluster mode's RedisExecutor); unset: the in-process
  // worker pool with `workers` threads.
  std::function<std::unique_ptr<Executor>(ExecutorCallbacks)> make_executor;
};

class JobManager {
 public:
  JobManager(ManagerConfig config, JobStore& store, JobCompiler compiler);
  ~JobManager();

  // Loads the store: finished jobs are served as stored, unfinished ones resume
  // from their last checkpoint, each owner's held to its running-jobs quota
  // (`max_running_of`; unset: unlimited) as new jobs are. Call once, before serving.
  using MaxRunningOf = std::function<uint64_t(const std::string& owner)>;
  void recover(const MaxRunningOf& max_running_of = {});

  // The spec compiled with `limits` (compile_within_budget): SpecError if it is invalid
  // or its state could never fit the memory budget.
  std::unique_ptr<JobDefinition> compile(const nlohmann::json& spec, const JobLimits& limits) const;
  // Memory for a state outside any job (a validate's pilot): charged against the
  // memory budget if it fits beside the jobs' states now, else false. Release it after.
  bool reserve_memory(uint64_t bytes);
  // JobError queue_full / quota if one more job of `who` would have no room to wait
  // (Admission::check_room): validate asks it before its pilot, as submit and extend do.
  void check_room(const Submitter& who) const;
  void release_memory(uint64_t bytes);
  // Throws SpecError (invalid spec) or JobError (queue full, shutting down). With
  // `use_cache`, a spec and seed equal to a finished job's that `who` may read is
  // answered from its stored result (ResultCache): a new job, finished at once.
  std::shared_ptr<Job> submit(const nlohmann::json& spec, int priority = 0, const Submitter& who = {},
                              bool use_cache = true);
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
  // The job waits again: JobError queue_full / quota as a submit of `who` would get.
  std::shared_ptr<Job> extend(const std::string& id, const StopRule& rule, const Submitter& who = {});

  // A queued or running job's priority from now on (-5..5, clamped): its place in the
  // queue (Admission orders by it at every start), which running job preemption pauses,
  // and its CPU share from its next chunk (Executor::set_priority). Acknowledged once
  // stored; if the store fails the old priority is put back (JobError unavailable).
  // JobError: not_found; conflict when the job has finished (or its result is being stored).
  std::shared_ptr<Job> set_priority(const std::string& id, int priority);

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
  // Bytes a job's state takes in memory (Admission::state_bytes).
  static uint64_t state_bytes(const JobDefinition& def) { return Admission::state_bytes(def); }

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
  // The executor dropped the job's partial pass: it ends failed (`error`) or cancelled.
  void on_stopped(const std::string& id, const std::optional<std::string>& error);
  void start_queued_locked();
  void job_left_scheduler(const Job& job);
  // Under mu_: a new job of `who` with the next id and sequence number.
  std::shared_ptr<Job> new_job_locked(const nlohmann::json& spec, int priority, const Submitter& who);
  // Under mu_: starts the job Admission picked (allocates its state, plans its first
  // pass, hands it to the executor).
  void start_locked(const std::shared_ptr<Job>& job);
  // A new job answered from a finished job's stored result (CachedAnswers::find), stored.
  std::shared_ptr<Job> answer_from(CachedAnswers::Answer answer, const nlohmann::json& spec, int priority,
                                   const Submitter& who, std::shared_ptr<const JobDefinition> def,
                                   const JobLimits& limits, const std::string& key);
  // On the recorder's loader thread: a parked job's state is read back; it starts.
  void resume_loaded(const std::shared_ptr<Job>& job);
  // Under mu_: asks the running jobs Admission picks to pause at their next pass boundary.
  void preempt_locked();
  // At a pass boundary (on_pass_done): queues the job again and frees its slot
  // (Preemption::requeue), then stores its state on the recorder's loader thread and
  // releases it (Preemption::release_stored).
  void pause(const std::shared_ptr<Job>& job);
  // Once a finished job is stored with its final checkpoint: frees its state.
  void release_state(Job& job);

  ManagerConfig config_;
  JobCompiler compiler_;
  JobRecorder recorder_;
  uint64_t epoch_ = 1;

  mutable std::mutex mu_;
  std::map<std::string, std::shared_ptr<Job>> jobs_;
  std::vector<std::shared_ptr<Job>> order_;   // submission order
  Admission admission_;                       // guarded by mu_
  int64_t next_seq_ = 1;
  bool shutting_down_ = false;
  uint64_t jobs_removed_ = 0;
  Preemption preemption_;                     // guarded by mu_ (drives admission_)

  JobStore& store_;
  FinishedStateCache finished_;  // its own lock
  JobRetention retention_;
  CachedAnswers answers_;  // its own lock

  std::unique_ptr<Executor> executor_;  // last: its workers call back into us
};

}  // namespace tally
