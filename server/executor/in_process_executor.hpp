#pragma once
// The in-process executor: a worker pool. Each running job contributes the blocks of its current pass,
// handed out in chunks. Scheduling is two-level stride scheduling: workers take the next
// chunk from the owner (principal) with the least virtual time, then from that owner's job
// with the least virtual time. A chunk charges its measured run time to its owner (all
// owners weigh the same) and, divided by the job's priority weight, to its job. So owners
// share the CPUs fairly first (8 jobs do not get 8x the CPU of 1), then an owner's jobs
// share its part, and a short job submitted behind a long one finishes promptly. Results land in per-block slots
// and are committed in block order by whoever finishes a pass's last chunk, so the
// bits do not depend on worker count, chunking or other jobs. A streamed job
// (ExecutorJob::stream_groups) has its result groups handed back in order as they
// complete (group_done, one worker at a time), and no worker starts a chunk more than
// 4 x workers groups past the last one handed back: its pass holds a few groups'
// results beside the state, never a pass's worth.
#include <atomic>
#include <condition_variable>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "server/executor/executor.hpp"

namespace tally {

// CPU share is proportional to priority_weight(priority).
int clamp_priority(int priority);
double priority_weight(int priority);

class InProcessExecutor final : public Executor {
 public:
  InProcessExecutor(unsigned workers, ExecutorCallbacks callbacks, double chunk_target_seconds = 0.004);
  ~InProcessExecutor() override;
  InProcessExecutor(const InProcessExecutor&) = delete;
  InProcessExecutor& operator=(const InProcessExecutor&) = delete;

  void add(ExecutorJob job, PassWork first_pass) override;
  bool cancel(const std::string& id) override;
  // The job's weight from its next chunk; its virtual time so far stays charged.
  void set_priority(const std::string& id, int priority) override;
  // The weight the job's chunks are charged with now (0 if it is not here): tests.
  double weight_of(const std::string& id) const;
  // Finishes the chunks in flight, drops partial passes, joins the workers.
  void stop() override;
  ExecutorStats stats() const override;

  unsigned workers() const { return static_cast<unsigned>(threads_.size()); }
  size_t scheduled_jobs() const;
  uint64_t samples_done() const { return samples_done_.load(std::memory_order_relaxed); }
  unsigned busy_workers() const { return busy_.load(std::memory_order_relaxed); }

 private:
  struct Active {
    uint64_t run = 0;  // this executor's serial number of the add(): tells a re-added job's new run from the old
    std::string id;
    std::string owner;
    std::shared_ptr<const Kernel> kernel;
    double weight = 1.0;
    double vtime = 0.0;
    PassWork pass;  // blocks being computed, with their pass input
    std::vector<BlockResult> results;
    // Blocks whose result a worker folded into its group's first as it computed them
    // (combine_groups' `folded`): a pass of several blocks per tile then holds about
    // one result per group, not one per block.
    std::vector<uint8_t> folded;
    // Streamed (stream_groups): groups computed (1) and handed back (delivered, in
    // order), the group that starts at `next`, whether a worker is handing groups back
    // now (at most one per job), and whether combining a group failed (the rest of the
    // pass is not handed back; pass_done then has fewer groups than the pass).
    bool stream = false;
    std::vector<uint8_t> computed;
    size_t delivered = 0;
    size_t next_group = 0;
    bool delivering = false;
    bool broken = false;
    size_t next = 0;       // next block to hand out
    size_t done = 0;       // blocks finished
    unsigned inflight = 0; // chunks running
    double block_seconds = 0.0;  // running estimate of one block's run time
    std::chrono::steady_clock::time_point pass_start;
    bool pass_started = false;
    bool committing = false;
    bool cancel_requested = false;
    // Set on cancel and stop: blocks in flight return early (block_abandon.hpp) and
    // their results are dropped.
    std::atomic<bool> abandon{false};
  };

  void worker_loop();
  Active* pick_locked();
  size_t chunk_size_locked(const Active& a) const;
  void start_pass_locked(Active& a, PassWork pass);
  // Hands `a`'s computed groups back in order (group_done) until the next one is not
  // computed; unlocks `lock` around each call. Returns at once if another worker is at it.
  void deliver_locked(std::unique_lock<std::mutex>& lock, Active& a);
  // Groups a streamed job may be computed ahead of the last one handed back.
  size_t stream_window() const { return 4 * threads_.size(); }
  double min_vtime_locked(const std::string& owner) const;
  double min_owner_vtime_locked() const;

  struct Owner {
    double vtime = 0.0;  // run time charged to the owner (the first level of the stride scheduler)
    size_t jobs = 0;     // its jobs in active_
  };

  ExecutorCallbacks cb_;
  double chunk_target_;
  mutable std::mutex mu_;
  std::condition_variable cv_;
  std::map<std::string, std::unique_ptr<Active>> active_;
  std::map<std::string, Owner> owners_;               // owners with a job in active_
  uint64_t runs_ = 0;                                  // add() calls so far (Active::run)
  std::map<std::string, double> cpu_seconds_by_owner_;  // measured chunk run time since start
  void erase_locked(std::map<std::string, std::unique_ptr<Active>>::iterator it);
  std::string last_picked_;
  bool stopping_ = false;
  std::atomic<uint64_t> samples_done_{0};
  std::atomic<uint64_t> groups_streamed_{0};
  std::atomic<unsigned> busy_{0};
  std::vector<std::thread> threads_;
};

}  // namespace tally
