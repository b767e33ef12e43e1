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

// Runs `blocks` by result group (`groups`: JobRunner::result_groups) on `threads` threads:
// a thread takes a whole group and combines each of its blocks into the group's first as
// it computes them (combine_results, block order: the bits of combine_groups), so a pass
// holds one result per group, not per block. Result g belongs to group g. Returns false
// if `cancel` was raised before all groups ran.
bool run_groups(const Kernel& kernel, const std::vector<Block>& blocks, const std::vector<ResultGroup>& groups,
                unsigned threads, std::vector<BlockResult>& results, const std::atomic<bool>* cancel = nullptr,
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
