#pragma once
// Admission: which jobs wait, which may start next, and whether there is room for one
// more. Owns the queue, the running count (overall and per owner) and the memory the
// jobs' states are charged against the budget (--memory-budget). Every path that makes
// state goes through it: submit, extend and recovery ask check_room() with the same
// rules and messages, and a job's state is charged here before it is allocated.
//
// Not thread-safe by itself: the job manager calls it under its own lock.
#include <algorithm>
#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "common/engine/job_definition.hpp"
#include "common/engine/limits.hpp"
#include "server/jobs/job.hpp"
#include "server/jobs/job_error.hpp"

namespace tally {

// Who submits a job and within which limits. The default is the anonymous owner
// with the server's own limits (no access control).
struct Submitter {
  std::string owner;
  uint64_t max_running = UINT64_MAX;  // the owner's jobs computing at once; more wait in the queue
  uint64_t max_queued = UINT64_MAX;   // the owner's jobs waiting; beyond: JobError quota
  std::optional<JobLimits> limits;    // per-job limits and caps; nullopt: the server's
  bool reads_all = true;              // may read every owner's jobs (admin, or no access control)
};

class Admission {
 public:
  struct Limits {
    size_t max_running = 16;     // jobs sharing the workers at once
    size_t max_queued = 256;     // jobs waiting for a running slot
    uint64_t memory_budget = 0;  // bytes of job state in memory at once; 0: no budget
  };
  explicit Admission(Limits limits) : limits_(limits) {}

  // Bytes a job's state takes in memory: job_state_bytes (common/engine/job_state.hpp)
  // of its kernel's channels and partitions, the estimate the spec readers check
  // against JobLimits::max_state_bytes.
  static uint64_t state_bytes(const JobDefinition& def);
  // What the budget is charged for a job: its state and what its kernel holds
  // (Kernel::resident_bytes: a lighting job's scene).
  static uint64_t memory_bytes(const JobDefinition& def);
  // Why a job whose state needs `need` bytes could never run, or nullopt if it fits the
  // budget alone (the refusal's text; the caller names the field).
  std::optional<std::string> over_budget(uint64_t need) const;

  // JobError queue_full (the server's queue) or quota (the owner's max_queued) when one
  // more job of `who` would have to wait and has no room to.
  void check_room(const Submitter& who) const;

  // Knows a job from now on: its state size and its owner's running-jobs quota.
  void track(const Job& job, uint64_t state_bytes, uint64_t owner_max_running);
  // Deleted: uncharged and forgotten.
  void forget(const Job& job);

  void enqueue(std::shared_ptr<Job> job);
  // Takes a queued job out of the queue (a cancel); false if it was not queued.
  bool dequeue(const Job& job);
  // The next job that may start, taken out of the queue, or null: no running slot, every
  // waiting owner at its running quota, or the first in line waits for memory (highest
  // priority first, then submission order; jobs already holding their state may pass it).
  std::shared_ptr<Job> next();

  // Whether `bytes` more fit beside the states charged now (always with none charged).
  bool fits(uint64_t bytes) const {
    return limits_.memory_budget == 0 || memory_used_ == 0 || memory_used_ + bytes <= limits_.memory_budget;
  }
  // Memory held outside any job (a validate's pilot run): charged if it fits beside the
  // states charged now; false (nothing charged) if not.
  bool reserve(uint64_t bytes) {
    if (limits_.memory_budget > 0 && memory_used_ + bytes > limits_.memory_budget) return false;
    memory_used_ += bytes;
    return true;
  }
  void unreserve(uint64_t bytes) { memory_used_ -= std::min(bytes, memory_used_); }
  // Its state is in memory (counted against the budget) / left memory.
  void charge(const Job& job);
  void release(const Job& job);
  bool charged(const Job& job) const;

  // The job computes / stopped computing (finished, failed, cancelled or paused).
  // `now`: when it started (steady clock seconds), for the preemption guard.
  void started(const std::shared_ptr<Job>& job, double now = 0);
  void stopped(const Job& job);

  // Preemption: the running job to pause at its next pass boundary so that a waiting one
  // can start, or null. Only while every running slot is taken, for the waiting job that
  // would start next (the order of next(), owners at their running quota skipped): a
  // running job of lower priority, or of an owner above its fair share (the running
  // slots split evenly over the owners with jobs running or waiting) while the waiting
  // job's owner is below it and the running job's priority is not higher. Of those, the
  // lowest priority, then the latest submitted; never one that started (or resumed)
  // less than `min_run_s` ago, nor one already chosen (until it stops).
  std::shared_ptr<Job> preemption_victim(double now, double min_run_s);

  // Whether the job's owner has as many jobs running as its quota allows.
  bool owner_at_quota(const Job& job) const {
    const Entry* e = entry(job);
    return e && running_of(job.owner()) >= e->owner_max_running;
  }

  size_t queued() const { return queue_.size(); }
  size_t running() const { return running_; }
  uint64_t memory_used() const { return memory_used_; }
  uint64_t memory_budget() const { return limits_.memory_budget; }
  const std::vector<std::shared_ptr<Job>>& queue() const { return queue_; }

 private:
  struct Entry {
    uint64_t state_bytes = 0;
    uint64_t owner_max_running = UINT64_MAX;
    bool charged = false;
  };
  const Entry* entry(const Job& job) const;
  uint64_t running_of(const std::string& owner) const;

  Limits limits_;
  std::map<std::string, Entry> entries_;      // by job id
  std::vector<std::shared_ptr<Job>> queue_;   // waiting to run, in arrival order
  size_t running_ = 0;
  std::map<std::string, uint64_t> running_by_owner_;
  uint64_t memory_used_ = 0;  // sum of state_bytes of charged jobs
  struct Running {
    std::shared_ptr<Job> job;
    double since = 0;     // steady seconds at its (re)start
    bool chosen = false;  // picked by preemption_victim
  };
  std::vector<Running> running_jobs_;
};

}  // namespace tally
