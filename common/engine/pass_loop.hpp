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

// Runs the pass `runner` has just planned (`blocks`: what plan_pass returned) on
// `threads` threads and merges it, all but JobRunner::finish_pass: a thread takes a whole
// result group, combines each of its blocks into the group's first as it computes them
// (combine_results, block order), and finished groups merge into the runner in group
// order (JobRunner::merge_group) as soon as those before them are in: the bits of
// commit_pass. No thread starts a group more than 4 x threads past the first one not yet
// merged, so a pass holds about that many group results beside the state, never a copy
// of it. Returns false if `cancel` was raised before every group merged (groups merged
// by then stay merged).
bool run_pass(JobRunner& runner, const std::vector<Block>& blocks, unsigned threads,
              const std::atomic<bool>* cancel = nullptr);

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
