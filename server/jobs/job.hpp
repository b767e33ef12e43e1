#pragma once
// One job as the server holds it: the immutable submission, its event log and
// its mutable state. The state is private: only the manager (lifecycle) and the
// recorder (persistence, recovery) touch it, under the job's lock. Everyone else
// reads a JobSnapshot (JobManager::snapshot) and never locks a job.
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <vector>
#include <nlohmann/json.hpp>
#include <string>

#include "common/engine/job_definition.hpp"
#include "common/engine/job_runner.hpp"
#include "common/protocol/job_snapshot.hpp"
#include "server/executor/executor.hpp"
#include "server/jobs/event_log.hpp"
#include "server/jobs/job_retention.hpp"
#include "server/jobs/manager_stats.hpp"

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

double unix_now();  // seconds since the epoch (system clock)
std::string new_job_id();  // 16 random hex digits

class Job : public std::enable_shared_from_this<Job> {
 public:
  Job(std::string id, int64_t seq, nlohmann::json spec, int priority, double created_at, uint64_t epoch,
      size_t event_buffer, std::string owner = {});

  const std::string& id() const { return id_; }
  int64_t seq() const { return seq_; }
  const nlohmann::json& spec() const { return *spec_; }
  // The spec as JSON text, written once (the store and remote workers read it).
  const std::string& spec_text() const { return spec_text_; }
  // Changed only by JobManager::set_priority, under the manager's lock and the job's:
  // Admission reads it under the former, snapshots and saves under the latter.
  int priority() const { return priority_.load(std::memory_order_relaxed); }
  // The principal that submitted it ("" without access control).
  const std::string& owner() const { return owner_; }
  double created_at() const { return created_at_; }
  // Thread-safe by itself (its own lock); the event streams read it.
  EventLog& events() const { return events_; }
  // What a new or lagging watcher starts with (JobManager::watch_snapshot). Takes mu_.
  std::vector<Event> watch_snapshot() const;
  // The job as it is now (JobManager::snapshot), with what `executor` says of it (asked
  // before the job's lock is taken: executor locks are never nested in it). Takes mu_.
  JobSnapshot snapshot(const Executor& executor, bool with_runner) const;

  // Part of a pass is merged (streamed), not all of it: the state is not at a pass
  // boundary and is no checkpoint. Takes state_mu_.
  bool mid_pass() const;

 private:
  friend class JobManager;
  friend class JobRecorder;
  friend class Preemption;
  friend class CachedAnswers;
  friend std::vector<JobRetention::Finished> finished_jobs(const std::vector<std::shared_ptr<Job>>&);
  friend void add_job_figures(ManagerStats&, const std::vector<std::shared_ptr<Job>>&, unsigned);

  // The picture routes read; call under mu_. `with_runner`: also a copy of the runner
  // (else one is made only when the views built at the pass boundary are missing).
  JobSnapshot snapshot_locked(bool with_runner) const;
  // Under mu_: the progress event data for the job's current version (built once per
  // version, shared by every watcher).
  std::shared_ptr<const std::string> watch_progress_locked() const;
  // Under mu_: a "state" event for the job as it is now.
  void publish_state_locked();
  // Under mu_: ends the job. `views`: its last views, built without the lock
  // (JobManager::on_pass_done); null: built here (a cancel or failure, whose runner has
  // not changed since its last pass; or `status` for a job that never started).
  void finish_locked(double now, std::optional<JobStatus> status = std::nullopt, const FinishViews* views = nullptr);
  // finish_locked in two steps: what the end sets (built, not applied), then applying
  // it with its events. on_pass_done stores the ending between the two.
  JobEnding ending_locked(double now, std::optional<JobStatus> status, const FinishViews* views) const;
  void end_locked(const JobEnding& ending, const FinishViews* views);

  // The lifecycle's steps on this job (the manager decides, under its lock, and calls
  // them under mu_):
  // queued -> running: allocates the state if it has none, plans the first pass and
  // fills `ej`. nullopt: not startable (no longer queued, no definition); an empty pass:
  // nothing to run, the job has ended (finish_locked).
  std::optional<PassWork> start_running_locked(uint64_t epoch, double now, ExecutorJob& ej);
  // The state leaves memory, the figures stay (facts_): read back when it starts.
  void park_locked();
  // running -> queued at a pass boundary, its state still in memory (stored next, then
  // parked: Preemption). Returns the samples it had.
  uint64_t pause_locked();
  // A finished job waits again with `runner` (the old one's state, the new rule); with
  // `park`, on disk.
  void reopen_locked(JobRunner runner, bool park);
  // A finished job reopened with `rule` (reopen_locked), its state in memory or `loaded`
  // (read back from the store; then it stays parked, the result). JobError conflict,
  // naming the job, if it is not finished, failed or the rule is already met; then
  // `check_room` (JobError if there is no room to wait). The job is untouched if refused.
  bool extend_locked(const StopRule& rule, std::unique_ptr<JobRunner> loaded, const std::function<void()>& check_room);
  // A queued or running job's priority from now on (takes mu_); returns the old one.
  // JobError conflict, naming the job, once it has finished (or is being stored), unless
  // `put_back` (a change the store did not take is undone whatever the job's state).
  int set_priority(int priority, bool put_back = false);
  // A queued job is cancelled at once.
  void cancel_queued_locked(double now);
  // A parked job's state read back (null: `error`): running can start, or it failed.
  bool resumed_locked(std::unique_ptr<JobRunner> runner, const std::string& error, double now);
  // A new job answered from a finished job's result and facts.
  void answer_locked(std::shared_ptr<const JobDefinition> def, JobCaps caps, const JobEnding& ending);
  // A pass boundary (JobManager::on_pass_done), in three steps. First merge_pass (below),
  // then under mu_: what comes next: the next pass, or the end (the rule is met, nothing
  // is left, or a cancel), or a pause (preempt_requested_), and whether a checkpoint is
  // due.
  struct PassCommit {
    PassWork next;
    bool finished = false, checkpoint = false, cancel_now = false, pause_now = false;
    uint64_t version = 0;
  };
  PassCommit commit_pass_locked(double checkpoint_interval_s);
  // Before commit_pass_locked, under state_mu_ and not mu_: the pass's results merged into
  // the runner (seconds for a 4K frame), with merging_ set meanwhile, so that status
  // reads, watchers and metrics (under mu_ alone, some on the I/O threads) never wait
  // for it. A merge that throws fails the runner (under mu_), as a kernel bug must.
  // `results` empty: the pass was streamed (merge_group), it is finished here.
  void merge_pass(std::vector<BlockResult>&& results, double wall, uint64_t pass);
  // A streamed pass (ExecutorJob::stream_groups): result group `group` of `pass` merged
  // into the runner as the executor hands it back, under state_mu_ (merging_ set
  // meanwhile), after any checkpoint being written from the live state (hold_merges).
  // A merge that throws fails the runner at merge_pass; later groups are dropped.
  void merge_group(BlockResult&& result, uint64_t pass, size_t group);
  // A checkpoint streams from the live state at a pass boundary: the next pass's
  // groups wait in merge_group until it is stored (JobRecorder::checkpoint_later).
  void hold_merges();
  void release_merges();
  bool merges_held();
  // Then, taking mu_ itself: the pass's heavy views (progress, tiles, status; for the
  // last pass the final ones, into `views`) built without the lock, then published.
  // Returns the job's ending when it finished (stored before it is published).
  JobEnding publish_pass(const std::vector<Block>& blocks, const PassCommit& c, FinishViews& views);
  // Adds this job's forecast of CPU-seconds left (ManagerStats), `share`: the workers a
  // running job has.
  void forecast_locked(double share, double& running, double& queued) const;

  const std::string id_;
  const int64_t seq_;
  const std::shared_ptr<const nlohmann::json> spec_;
  const std::string spec_text_;
  std::atomic<int> priority_;
  const double created_at_;
  const std::string owner_;
  mutable EventLog events_;
  // The result cache's key (ResultCache::key_of; "" : never cached) and, for a job
  // answered from it, the job whose stored result it took. Set before the job is shared.
  std::string cache_key_;
  std::string cached_from_;
  // Bytes of the job's row in the store (spec, result, checkpoint), for retention.
  std::atomic<uint64_t> stored_bytes_{0};

  // Held by a pass's commit while it changes runner_'s state, and by a checkpoint
  // streaming that state to the store (JobRecorder::store, no copy of it) while it
  // encodes a piece; not while the store writes one. A commit so waits for one piece
  // at most; the checkpoint then finds the state's passes changed and is abandoned.
  // Taken before mu_. Also held for a pass's merge (merge_pass, without mu_) and by
  // whoever reads the runner itself rather than its views (a snapshot with the runner,
  // a checkpoint's take).
  mutable std::mutex state_mu_;
  // The job's last checkpoint streamed from the live state was abandoned: the next one
  // holds state_mu_ for its whole write (JobRecorder::store).
  std::atomic<bool> checkpoint_abandoned_{false};
  // Streamed merges held while a checkpoint is written (hold_merges).
  std::mutex merge_gate_mu_;
  std::condition_variable merge_gate_cv_;
  bool merges_held_ = false;  // guarded by merge_gate_mu_
  std::string stream_error_;  // guarded by state_mu_: a streamed group's merge failed this pass

  mutable std::mutex mu_;
  // --- guarded by mu_ ---
  std::shared_ptr<const JobDefinition> def_;  // null if the stored spec no longer compiles
  // The channel state, in memory only while the job runs (and for queued jobs resumed
  // from a checkpoint or extended): null before it starts, once finished and stored,
  // or if it could not be restored. facts_ then says what the views show.
  // Shared with a checkpoint being written (JobRecorder), which reads its state in
  // place under state_mu_: the state is never changed in place but by a pass's commit
  // (under state_mu_, which changes its passes); whatever else changes the runner
  // replaces it.
  std::shared_ptr<JobRunner> runner_;
  std::shared_ptr<const RunFacts> facts_;
  JobCaps caps_;  // the runner's caps, fixed at submission
  JobStatus status_ = JobStatus::queued;
  std::string error_;
  double started_at_ = 0, finished_at_ = 0;
  std::shared_ptr<const nlohmann::json> final_result_;  // engine part of a finished job's status (also stored)
  uint64_t version_ = 1;  // bumped on every change: keys snapshots, the status cache and saves
  mutable std::shared_ptr<const JobRunner> published_;  // copy of runner_ at published_version_
  mutable uint64_t published_version_ = 0;
  // The documents of a job with a runner but no pass views of this process at its version
  // (resumed at start, paused and queued): built from runner_ under mu_ once per version,
  // without copying its state (snapshot_locked).
  void build_idle_views_locked() const;
  mutable std::shared_ptr<const nlohmann::json> idle_engine_;
  mutable std::shared_ptr<const RunFacts> idle_facts_;
  mutable uint64_t idle_version_ = 0;
  // The data of a watcher snapshot's progress event, built once per version off
  // the I/O threads (on_pass_done, finish) and shared by every watcher.
  mutable std::shared_ptr<const std::string> watch_progress_;
  mutable uint64_t watch_progress_version_ = 0;
  // A committed pass whose progress event is not yet in the log (on_pass_done builds it
  // without the lock): a snapshot then shows the last published progress, or none, and
  // the new one follows live — never the same pass twice.
  bool publishing_ = false;
  // A pass, or one result group of a streamed pass, is being merged into runner_
  // (merge_pass, merge_group: under state_mu_, not mu_). Between a streamed pass's group
  // merges the runner holds part of that pass (every tile whole; samples, passes and the
  // trace move at merge_pass), which a reader of the state itself may see. Readers
  // under mu_ alone then leave runner_ alone and show the last boundary's views (engine_,
  // live_facts_, watch_progress_, idle views); whoever needs the runner itself takes
  // state_mu_ first (a snapshot with the runner, a checkpoint's take).
  bool merging_ = false;
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
  // Queued with its state on disk (its stored checkpoint), not in memory: extended from
  // disk, paused for a job that goes first (preempted_), or resumed at start beyond the
  // memory budget. Its state is read back (JobRecorder::read_back) when it starts;
  // loading_ while that read is under way.
  bool parked_ = false;
  bool loading_ = false;
  // Preemption: to pause at its next pass boundary (a job that goes first waits), and
  // paused so (queued until it resumes: waiting_reason "preempted").
  bool preempt_requested_ = false;
  bool preempted_ = false;
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
