#pragma once
// Drives one job through progressive passes: plans each pass as a list of blocks,
// merges their results in block order, by result group (Kernel's PassSchedule::
// group_blocks; so any thread count, chunking or machine gives the same bits), keeps the convergence trace and decides when to stop. It runs no
// threads itself: the in-process pass loop (common/engine/pass_loop.hpp) and the
// server's scheduler both call plan_pass / commit_pass.
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "common/engine/job_state.hpp"
#include "common/engine/kernel.hpp"
#include "common/engine/limits.hpp"
#include "common/engine/stop_rule.hpp"

namespace tally {

struct Estimate {
  uint64_t n = 0;
  double mean = 0.0;
  double variance = 0.0;  // of one sample
  double std_error = 0.0;
  double rel_error = 0.0;  // std_error / |mean|
  double ci_lo = 0.0;
  double ci_hi = 0.0;
  double confidence = 0.95;
};

// Samples and compute time still needed to reach the error target.
struct Prediction {
  double samples_needed = 0.0;  // in total
  double samples_remaining = 0.0;
  double seconds_remaining = 0.0;
};

struct CostPoint {
  double rel_error = 0.0;
  double samples = 0.0;
  double seconds = 0.0;
};

class JobRunner {
 public:
  JobRunner(std::shared_ptr<const Kernel> kernel, StopRule rule, JobCaps caps);
  // Resume from a checkpointed state.
  JobRunner(std::shared_ptr<const Kernel> kernel, StopRule rule, JobCaps caps, JobState restored);

  // Blocks of the next pass; empty once finished. Call commit_pass before planning again.
  std::vector<Block> plan_pass();
  // The kernel's input for the pass just planned (Kernel::pass_input); pass it to
  // Kernel::run_block_with for each of its blocks. Empty for non-adaptive kernels.
  const std::string& pass_input() const { return pass_input_; }
  // The pass plan_pass will return once the pass just planned is committed, planned now:
  // only when nothing it depends on can come from that pass's results (the rule has no
  // error target and no time budget; the kernel plans from sample counts alone,
  // Kernel::plans_from_counts) and the job does not stop at its sample limit after it.
  // Else nullopt. An executor may compute it early (PassWork::ahead) and must use what
  // it computed only if the pass planned after the commit is equal: a stop the counts do
  // not foresee (a fault, the compute-time cap, a cancel) leaves it unused.
  // `followed` (if given): whether the counts plan yet another pass after that one.
  std::optional<std::vector<Block>> plan_ahead(bool* followed = nullptr) const;
  // The pass just planned cut into result groups (result_groups with the kernel's
  // group_blocks): commit_groups takes one combined result per group.
  const std::vector<ResultGroup>& result_groups() const { return groups_; }
  // `results[i]` belongs to the i-th planned block: combined by result group, then
  // committed as commit_groups. `wall_seconds`: the pass's duration.
  void commit_pass(std::vector<BlockResult>&& results, double wall_seconds);
  // `results[g]` is result group g's blocks combined in block order (combine_results),
  // wherever that happened: the same bits as commit_pass of the blocks' results.
  void commit_groups(std::vector<BlockResult>&& results, double wall_seconds);
  // commit_groups streamed: result group g's combined result for g = 0, 1, ... in order,
  // each merged into the state at once and freed (an image's pass never holds all its
  // results: the in-process loop merges a group as soon as those before it are in), then
  // finish_pass once every group is in: the same bits as commit_groups. Until then the
  // state holds the groups merged so far with their partitions' samples counted (every
  // tile of an image consistent); passes, samples, the trace and error() move at
  // finish_pass. A kernel that folds passes (Kernel::folds_passes) has its results held
  // until finish_pass. A cancel between them keeps what was merged.
  void merge_group(BlockResult&& result);
  void finish_pass(double wall_seconds);
  // Result groups of the pass in flight merged (or held) so far.
  size_t groups_merged() const { return merged_ + held_.size(); }

  bool finished() const { return reason_ != StopReason::none; }
  StopReason stop_reason() const { return reason_; }
  // Ends the job; a pass in flight is dropped (groups it merged already stay merged).
  void cancel();
  void fail(std::string message);
  // Reopen with a new rule (more samples, a tighter target): `POST .../extend`.
  void extend(const StopRule& rule);

  const JobState& state() const { return state_; }
  const StopRule& rule() const { return rule_; }
  const JobCaps& caps() const { return caps_; }
  const Kernel& kernel() const { return *kernel_; }
  const std::optional<std::string>& error_message() const { return error_; }

  Estimate estimate(size_t channel = 0) const;
  // What progress shows: the kernel's headline (e.g. an image's mean) or channel 0.
  Estimate headline() const;
  // The kernel's error summary of the state (Kernel::error_summary), computed once per
  // state and rule (at construction, commit and extend: for an image it is a pass over
  // every pixel, and progress, status, the stop rule and forecasts all ask for it).
  const ErrorSummary& error() const { return error_summary_; }
  double samples_per_second() const;
  bool target_met() const;
  std::optional<double> tail_alpha() const;
  bool heavy_tail() const;
  std::optional<Prediction> prediction() const;
  // Seconds until the rule fires (error target, max_samples or time budget), from
  // the one forecast (common/engine/forecast.hpp); +inf when unknown.
  double eta_seconds() const;
  std::vector<CostPoint> cost_curve(const std::vector<double>& rel_levels) const;
  std::vector<std::string> warnings() const;

 private:
  // Samples of the pass after state `s` (the runner's, or plan_ahead's counts-only one).
  uint64_t next_pass_samples(const JobState& s) const;
  std::vector<Block> blocks_after(const JobState& s, uint64_t samples) const;
  // The counts after `pass` (of `samples`) is committed to `s`; nullopt when the job
  // ends there by its counts (its sample limit or cap).
  std::optional<JobState> counts_after(const JobState& s, const std::vector<Block>& pass, uint64_t samples) const;
  void evaluate_stop();
  void push_trace();
  void summarize_error() { error_summary_ = kernel_->error_summary(state_, rule_.confidence); }
  void merge_result(BlockResult& r, size_t group);

  std::shared_ptr<const Kernel> kernel_;
  StopRule rule_;
  JobCaps caps_;
  JobState state_;
  StopReason reason_ = StopReason::none;
  std::optional<std::string> error_;
  ErrorSummary error_summary_;  // of state_ under rule_.confidence (error())
  std::vector<Block> pending_;
  std::vector<ResultGroup> groups_;
  std::string pass_input_;
  uint64_t pending_samples_ = 0;
  size_t merged_ = 0;               // groups of the pending pass merged (merge_group)
  std::vector<BlockResult> held_;   // the pending pass's results, for a kernel that folds passes
};

}  // namespace tally
