#pragma once
// Persistence and recovery of jobs: what the manager saves at submission, at
// checkpoints and at the end, and how a restart turns stored rows back into jobs.
// Failures never take a job down silently: each is logged at warn with the job id
// and what it means for the job.
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <functional>
#include <map>
#include <mutex>
#include <optional>
#include <set>
#include <stop_token>
#include <thread>
#include <memory>
#include <nlohmann/json.hpp>
#include <vector>

#include "common/engine/checkpoint.hpp"
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
  // Saves a job that has no runner with `checkpoint` (encoded state bytes, e.g. another
  // job's stored state) as its checkpoint. Not retried.
  bool persist_with(Job& job, std::string checkpoint);
  // A periodic checkpoint of a running job: the state is copied now (under the job's
  // lock, on the caller's thread) and encoded and stored on the recorder's checkpoint
  // thread, so the pass that asked goes on at once (an image's checkpoint takes
  // hundreds of ms to encode and write; the workers would wait). One per job at a
  // time: while the job's previous checkpoint is still being written, this one is
  // skipped (the next interval takes it). Failures are handled as persist's, with retry.
  // One streamed from the live state holds the job's streamed merges (Job::hold_merges)
  // until it is stored: call it before the job's next pass is handed out.
  void checkpoint_later(const std::shared_ptr<Job>& job);
  // States whose checkpoint is estimated at most this many bytes are copied at the pass
  // boundary and encoded from the copy (never abandoned); larger ones stream from the
  // live state (see store()). Default: one checkpoint piece. Tests set 0 to stream all.
  void set_copy_bytes(uint64_t bytes) { copy_bytes_ = bytes; }
  // The save of a job that has ended at a pass boundary, with `ending` (its status,
  // result and facts, not yet published) and its final checkpoint, on the recorder's
  // finisher thread: the thread that ended it (a worker; in cluster mode the
  // coordinator, which publishes no pass of any job meanwhile) goes on at once. The
  // state is copied now, under the job's lock. `then(stored)` runs on the finisher
  // thread after the save, stored or not (a failure is logged and counted; not retried
  // here: `then` publishes the ending, and a save retried after that stores it). At most
  // kMaxQueuedFinals wait (each holds a copy of its job's state): beyond that the save
  // and `then` run here.
  void save_final_later(const std::shared_ptr<Job>& job, const JobEnding& ending,
                        std::function<void(bool stored)> then);
  static constexpr size_t kMaxQueuedFinals = 2;
  // Returns once every final save queued so far is written and its `then` has run.
  void flush_finals();
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

  // Once DELETE removed the job's row: a save still in flight or to come (a retry of a
  // failed final save runs after the job reads as finished) writes nothing, and the row
  // is deleted once more in case a save wrote it back meanwhile. Takes the job's save
  // lock only (the pass callback takes it under the manager's lock: never the other way).
  void removed(Job& job);

  // A runner with the job's stored state (its last checkpoint; a fresh state if none
  // was stored) and `rule`, to go on from where it stopped (extend, a paused job).
  // Reads the disk; throws if the stored state cannot be read.
  std::unique_ptr<JobRunner> read_back(const Job& job, const JobDefinition& def, const StopRule& rule) const;
  // Runs `task` on the recorder's loader thread, in arrival order: reads of stored
  // states (read_back) for jobs about to start, kept off the threads that start them.
  void load_later(std::function<void()> task);
  // Runs the tasks queued so far, then stops the loader: load_later runs a task on the
  // caller's thread after this. Call before whatever the tasks use goes away.
  void stop_loads();

 private:
  // What persist stores, taken under the job's lock (the state is encoded later).
  // With a checkpoint: the runner, read in place while it streams to the store, and
  // its passes then (a commit meanwhile abandons the checkpoint: Job::state_mu_).
  struct Pending {
    StoredJob row;
    uint64_t version = 0;
    // The state to checkpoint: a copy taken at the pass boundary when it is small
    // (copy_bytes_), else the live runner's, streamed piece by piece at `passes`.
    std::shared_ptr<const JobState> copy;
    std::shared_ptr<const JobRunner> runner;
    uint64_t passes = 0;
  };
  // The job's row as stored; with `ending`, as it will read once that ending is published.
  Pending take(Job& job, bool with_checkpoint, const JobEnding* ending = nullptr) const;
  bool store(Job& job, Pending pending, bool retry);
  void retry_saves(std::stop_token st);
  // While the store fails with nothing to retry: JobStore::probe, and on success the
  // store reads healthy again (/readyz 200 without waiting for a submit).
  void probe_store();
  static constexpr std::chrono::seconds kProbeInterval{1};
  void write_checkpoints(std::stop_token st);
  void write_finals(std::stop_token st);

  JobStore& store_;
  JobCompiler compiler_;
  JobLimits limits_;
  size_t event_buffer_;
  StoreHealth health_;
  std::mutex retry_mu_;
  std::condition_variable_any retry_cv_;
  std::map<std::string, std::weak_ptr<Job>> retry_;  // saves that failed, by job id
  std::jthread retrier_;                              // runs retry_saves
  std::mutex checkpoint_mu_;
  std::condition_variable_any checkpoint_cv_;
  std::vector<std::pair<std::shared_ptr<Job>, Pending>> checkpoints_;  // queued
  std::atomic<uint64_t> copy_bytes_{kCheckpointPieceBytes};
  std::set<std::string> checkpoint_busy_;  // ids of jobs whose checkpoint is queued or being written
  std::mutex finals_mu_;
  std::condition_variable_any finals_cv_;
  struct Final {
    std::shared_ptr<Job> job;
    Pending pending;
    std::function<void(bool)> then;
  };
  std::vector<Final> finals_;  // queued
  size_t finals_busy_ = 0;     // queued or being written
  std::jthread checkpointer_;  // runs write_checkpoints, stopped (and drained) after the finisher
  std::jthread finisher_;      // runs write_finals, stopped (and drained) first

  void run_loads(std::stop_token st);
  std::mutex loads_mu_;
  std::condition_variable_any loads_cv_;
  std::vector<std::function<void()>> loads_;  // queued
  bool loads_stopped_ = false;
  std::jthread loader_;  // last: runs run_loads
};

}  // namespace tally
