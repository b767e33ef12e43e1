#pragma once
// The in-process pass loop: runs a job on a few threads (the CLI's `tally run`, tests,
// the study, the validate pilot). Not an Executor (server/executor): no queue, no
// fairness, one job.
// The server has its own fair scheduler over the same JobRunner interface.
#include <atomic>
#include <functional>
#include <string_view>
#include <vector>

#include "common/engine/job_runner.hpp"

namespace tally {

// Runs `blocks` on `threads` threads; result i belongs to block i. Returns false if
// `cancel` was raised before all blocks ran (the results are then incomplete).
// `pass_input`: JobRunner::pass_input() of the pass the blocks belong to.
bool run_blocks(const Kernel& kernel, const std::vector<Block>& blocks, unsigned threads,
                std::vector<BlockResult>& results, const std::atomic<bool>* cancel = nullptr,
                std::string_view pass_input = {});

struct LocalRunOptions {
  unsigned threads = 1;
  std::function<void(const JobRunner&)> on_pass;  // after every committed pass
  const std::atomic<bool>* cancel = nullptr;      // raised: the pass in flight is dropped, the runner cancelled
  std::function<bool()> keep_going;               // asked before each new pass (the pilot's clock)
};

// The one local pass loop (`tally run`, tests, the study, the validate pilot):
// plan, run the blocks on `threads` threads, commit, until the runner finishes or
// `keep_going` says stop. Returns false if `cancel` cut a pass.
bool run_local(JobRunner& runner, const LocalRunOptions& options);
inline void run_local(JobRunner& runner, unsigned threads) {
  LocalRunOptions o;
  o.threads = threads;
  run_local(runner, o);
}

// Threads this process may use (affinity mask; at least 1).
unsigned available_cpus();

}  // namespace tally
