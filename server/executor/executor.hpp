#pragma once
// The seam between job management and computation. The manager hands an executor the
// blocks of one pass of a job; the executor computes them wherever it likes (threads in
// this process, workers behind Redis) and hands the pass back, one result per result
// group in block order (the blocks of a group combined, combine_results): all at once
// through ExecutorCallbacks::pass_done, or, for a job that asks (ExecutorJob::
// stream_groups) and an executor that can, group by group through group_done as they
// finish, so no whole pass of results is ever held (an image's is twice its state). Merge order, checkpoints, events and the
// stop rule live above this seam and never know which executor ran.
//
// Implementations: InProcessExecutor (server/executor/in_process_executor.hpp, the
// stride-scheduled worker pool). Thread-safety: every member function may be called from
// any thread; callbacks run on executor threads, never under an executor lock, and may
// call back into the executor (add, cancel).
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "common/engine/kernel.hpp"

namespace tally {

// What an executor needs to compute a job's blocks.
struct ExecutorJob {
  std::string id;
  std::shared_ptr<const Kernel> kernel;  // the compiled spec: in-process executors run this
  std::string spec_json;  // the spec as submitted (canonical JSON text): remote workers compile it
  uint64_t epoch = 0;     // bumped when the job is reopened (extend) or the server restarts;
                          // results tagged with an older epoch are never merged
  int priority = 0;       // CPU share within an owner, see priority_weight()
  std::string owner;      // the principal that submitted the job ("" without access control)
  // Hand the pass back group by group (ExecutorCallbacks::group_done) as the groups are
  // in, in order: the in-process executor computes only a few groups past the last one
  // handed back; the cluster's hands each on as soon as it has read it and those before
  // it. An executor that cannot hands back whole passes (pass_done with every group).
  bool stream_groups = false;
};

// One pass of a job: blocks planned by JobRunner::plan_pass, plus the kernel's input for
// that pass (JobRunner::pass_input(), empty unless the kernel adapts between passes).
struct PassWork {
  uint64_t pass = 0;  // JobState::passes when the pass was planned: with (job, epoch) it keys results
  std::vector<Block> blocks;
  // `blocks` cut into result groups (JobRunner::result_groups): pass_done takes one
  // combined result per group.
  std::vector<ResultGroup> groups;
  std::string pass_input;
  // The pass after this one, when it can be planned before this one's results are merged
  // (JobRunner::plan_ahead), else null. An executor may start computing it early; it
  // uses those results only if the pass pass_done returns for this one is the same
  // (same_plan), and drops them otherwise.
  std::shared_ptr<const PassWork> ahead;
  // Another pass is planned after this one before this one is merged (for the current
  // pass: `ahead` is set; for a pass ahead: JobRunner::plan_ahead's `followed`). Then
  // nothing waits for this pass's last block, and an executor need not cut its end into
  // small pieces to balance it (a cluster cuts it into equal entries).
  bool followed = false;
  bool empty() const { return blocks.empty(); }
};

// Same pass number, blocks and input: results computed for one belong to the other.
inline bool same_plan(const PassWork& a, const PassWork& b) {
  return a.pass == b.pass && a.pass_input == b.pass_input && a.blocks == b.blocks && a.groups == b.groups;
}

struct ExecutorCallbacks {
  // Every block of `done` has a result: results[g] is result group done.groups[g], its
  // blocks' results combined in block order (combine_results). Commit them and return
  // the job's next pass (empty: the job leaves the executor).
  std::function<PassWork(const std::string& id, const PassWork& done, std::vector<BlockResult>&& results,
                         double wall_seconds)>
      pass_done;
  // A streamed job's (ExecutorJob::stream_groups) result group `group` of `pass`: called
  // for group 0, 1, ... in order, one at a time per job (from any executor thread), as
  // soon as the groups before it are in; then pass_done with empty `results` once the
  // last one is. A cancel or stop may end the calls before the last group; the groups
  // handed back stay handed back. The call may block (the job holds its merges while
  // a checkpoint is written): the executor computes at most a few groups ahead meanwhile.
  std::function<void(const std::string& id, const PassWork& pass, size_t group, BlockResult&& result)> group_done;
  // Whether a streamed job's merges wait now (a checkpoint is being written from its
  // live state): group_done would block until they go on. An executor whose thread
  // serves other jobs too (the cluster's coordinator) hands the groups back later
  // instead. It becomes true only inside pass_done, so a thread that asked and got
  // false before calling group_done (with no pass_done in between) does not block.
  std::function<bool(const std::string& id)> merges_held;
  // A cancelled job has no block in flight any more; its partial pass is dropped.
  std::function<void(const std::string& id)> cancelled;
  // The executor gave up on the job (e.g. a block failed on every delivery); the job
  // has left the executor. Not called for cancelled jobs.
  std::function<void(const std::string& id, const std::string& error)> failed;
};

struct ExecutorStats {
  unsigned workers = 0;        // threads (in process) or live worker threads (cluster)
  unsigned busy_workers = 0;
  uint64_t samples_done = 0;   // computed since start
  uint64_t groups_streamed = 0;  // result groups handed back one by one (group_done) since start
  size_t scheduled_jobs = 0;
  // Cluster executors: blocks per job not yet handed out / handed out and not back /
  // handed out more than once.
  struct JobBlocks {
    uint64_t pending = 0, in_flight = 0, redelivered = 0;
  };
  std::map<std::string, JobBlocks> blocks_by_job;
  // Compute seconds spent on each owner's blocks since start (the fair-share accounting).
  std::map<std::string, double> cpu_seconds_by_owner;
};

class Executor {
 public:
  virtual ~Executor() = default;
  // Starts computing `first_pass` of a job not yet in the executor (ignored if empty or
  // after stop()).
  virtual void add(ExecutorJob job, PassWork first_pass) = 0;
  // Stops handing out the job's blocks. Returns false if the job is not in the executor.
  // The `cancelled` callback runs once no block is in flight (maybe on this thread).
  virtual bool cancel(const std::string& id) = 0;
  // The job's priority changed (PATCH /v1/jobs/{id}): its CPU share from its next chunk.
  // Executors that do not weigh jobs (cluster mode: workers take the blocks in order)
  // ignore it; the queue and preemption, above this seam, follow the job's priority.
  virtual void set_priority(const std::string& /*id*/, int /*priority*/) {}
  // Finishes or abandons what is in flight, drops partial passes, joins threads. No
  // callback runs after stop() returns.
  virtual void stop() = 0;
  virtual ExecutorStats stats() const = 0;
  // Empty when the executor can compute; otherwise why not (e.g. "redis unreachable").
  virtual std::optional<std::string> not_ready_reason() const { return std::nullopt; }
  // Why a job in the executor makes no progress right now (e.g. no cluster worker is
  // connected), for its status; empty when it is being computed.
  virtual std::optional<std::string> waiting_reason(const std::string& /*id*/) const { return std::nullopt; }
  // Whether a job in the executor reads as queued rather than running: nothing can
  // start computing it (cluster mode: no live worker serves its pool).
  virtual bool holds_queued(const std::string& /*id*/) const { return false; }
};

}  // namespace tally
