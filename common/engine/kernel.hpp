#pragma once
// The one abstraction every job kind implements: evaluate a block of samples for a
// range of channels. Integration and lighting differ only here; passes, stopping,
// streaming, checkpoints and images do not care which kind runs.
#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "common/engine/component_targets.hpp"
#include "common/engine/counters.hpp"
#include "common/engine/sample_stats.hpp"
#include "common/stats/tail_index.hpp"
#include "common/stats/tally.hpp"

namespace tally {

struct JobState;

// A unit of work: samples [first_sample, first_sample + sample_count) of one
// partition. Blocks are merged in `index` order (by result group, below), whatever
// thread or machine ran them.
struct Block {
  uint64_t index = 0;
  uint64_t first_sample = 0;
  uint64_t sample_count = 0;
  uint32_t partition = 0;  // kernel-defined, e.g. an image tile; 0 for dense kernels
  bool operator==(const Block&) const = default;
};

struct BlockResult {
  uint64_t block_index = 0;
  uint32_t first_channel = 0;
  std::vector<Tally> tallies;  // channels [first_channel, first_channel + size)
  // Sum channels [first_sum, first_sum + size) (Kernel::sum_count): each the plain sum of
  // the block's samples of that channel, added in sample order.
  uint32_t first_sum = 0;
  std::vector<double> sums;
  Counters counters;
  TailTracker tail{32};  // largest |values| of the headline channel
  WeightStats weights;
  std::optional<SampleFault> fault;
  // Kernel-defined per-block accumulators (e.g. VEGAS's per-bin sums), read by
  // Kernel::fold_pass in block order. Empty for most kernels.
  std::vector<double> aux;
};

struct ErrorSummary {
  double abs_error = 0.0;  // half-width of the interval at the job's confidence
  double rel_error = 0.0;  // half-width / |mean|
  double sigma = 0.0;      // per-sample standard deviation that drives the above
  double mean = 0.0;
};

// The single number a job's progress shows (CLI list/watch, progress events) when
// channel 0 alone would not mean much, e.g. an image's mean radiance.
struct Headline {
  double mean = 0.0;
  double std_error = 0.0;  // of `mean`
  // Sample count for critical_value() (n - 1 degrees of freedom); the default is the
  // normal limit. K for an error from K randomized-QMC replicates.
  uint64_t critical_n = UINT64_MAX;
};

struct PassSchedule {
  uint64_t first_pass_samples = 4096;  // pass k draws first * 2^k, up to the cap
  uint64_t max_pass_samples = 1u << 22;
  uint64_t block_samples = 4096;  // samples per block (the unit of parallel work)
  // Pass sizes are rounded up to a multiple of this (unless a sample limit forbids), e.g.
  // K so that K randomized-QMC replicates grow together.
  uint64_t sample_quantum = 1;
  // The results of up to this many consecutive blocks of one partition are combined
  // (combine_results, in block order) before they merge into the job's state: a pass
  // merges by result group (result_groups), so the bits do not depend on where the
  // combining happened, and an executor may combine where the blocks ran (a cluster
  // worker sends one result per group, not per block). 1: every block merges alone.
  // Kernels with BlockResult::aux (read by fold_pass) keep 1.
  uint64_t group_blocks = 1;
};

// Consecutive blocks of a pass whose results combine before they merge: slots
// [first, first + count) of the pass's block list.
struct ResultGroup {
  size_t first = 0;
  size_t count = 0;
  bool operator==(const ResultGroup&) const = default;
};

// A pass's blocks cut into result groups: a group ends after `group_blocks` blocks or
// where the partition changes. Cutting any run of whole groups (e.g. a stream entry
// that starts where a group starts and ends where one ends) gives the same groups.
std::vector<ResultGroup> result_groups(std::span<const Block> blocks, uint64_t group_blocks);

// Adds the result of the block after those `acc` holds (same partition, same channel
// range, no aux) to `acc`: tallies, counters, tail and weights merge; the first fault in
// block order stays. `acc` keeps its block_index (the group's first block).
void combine_results(BlockResult& acc, const BlockResult& next);
// One result per group from one result per block (moved from): what a pass merges.
// `folded` (empty, or one flag per block): block i's result was combined into its
// group's first already, in block order, as it was computed (an executor whose worker
// computed the group's blocks from its first one on); it is skipped. Folded blocks are
// the ones right after their group's first.
std::vector<BlockResult> combine_groups(std::vector<BlockResult>&& per_block, std::span<const ResultGroup> groups,
                                        std::span<const uint8_t> folded = {});

class Kernel {
 public:
  virtual ~Kernel() = default;
  virtual size_t channel_count() const = 0;
  // Sum channels: a float per channel (JobState::sums) where a tally takes 24 bytes, for
  // kernels whose channels of one partition all receive the same number of samples, a
  // number the kernel derives from JobState::partition_samples (e.g. an image's
  // randomized-QMC replicates: every pixel of a tile gets the same points). The engine
  // only adds them, in block order. Default: none.
  virtual size_t sum_count() const { return 0; }
  // A state in an older layout of this kernel's (from a checkpoint an earlier build
  // wrote), converted in place to the current one (channel_count, sum_count); false if
  // `state` is in no layout it knows. Default: false.
  virtual bool upgrade_state(JobState& /*state*/) const { return false; }
  virtual uint32_t partition_count() const { return 1; }
  virtual PassSchedule schedule() const { return {}; }
  // Partitions that get samples in the next pass (adaptive sampling skips converged
  // ones). Must be a deterministic function of the state.
  virtual std::vector<uint32_t> active_partitions(const JobState& state) const;
  // Thread-safe and pure: the result depends on the block alone.
  virtual void run_block(const Block& block, BlockResult& out) const = 0;
  // Adaptive kernels (e.g. VEGAS) change between passes. `pass_input` is what the next
  // pass needs besides its blocks, as bytes, computed deterministically from the merged
  // state (JobRunner::plan_pass calls it); every executor hands those bytes back to
  // `run_block_with` for each block of that pass (remote workers receive them with the
  // blocks). Default: no input, and run_block_with is run_block.
  virtual std::string pass_input(const JobState&) const { return {}; }
  // True if the next pass's plan (active_partitions) depends on the state's sample
  // counts alone, never on merged results, and there is no pass input: then
  // JobRunner::plan_ahead may plan a pass before the one before it is merged, and a
  // cluster starts it early. Default false (opt in; adaptive kernels stay false).
  virtual bool plans_from_counts() const { return false; }
  virtual void run_block_with(const Block& block, std::string_view /*pass_input*/, BlockResult& out) const {
    run_block(block, out);
  }
  // Adaptive kernels: fold a finished pass's results (in block order, before the
  // runner merges them; one per result group, i.e. per block for group_blocks 1) into
  // state.kernel_state, which the next pass_input reads.
  // Must be deterministic in (pass_input, results, state). Default: nothing.
  virtual void fold_pass(std::string_view /*pass_input*/, const std::vector<BlockResult>& /*results*/,
                         JobState& /*state*/) const {}
  // True if fold_pass does anything: then the runner holds a pass's results until the
  // last one is in (JobRunner::merge_group), since fold_pass reads them all before any
  // merges. Default false: each result merges as it arrives.
  virtual bool folds_passes() const { return false; }
  // The kernel's event counters, by id: BlockResult::counters and JobState::counters
  // are indexed by position in this list (the names appear in status documents and
  // checkpoints). Must not change over the kernel's life. Default: none.
  virtual std::span<const std::string_view> counter_names() const { return {}; }
  // Kernel-specific warnings (e.g. VEGAS iterations that disagree, rejection sampling
  // that rarely accepts: what the kernel's own counters mean). Default: none.
  virtual std::vector<std::string> warnings(const JobState&) const { return {}; }
  // The error the stopping rule looks at. Default: the worst channel.
  virtual ErrorSummary error_summary(const JobState& state, double confidence) const;
  // Each component's error, read against StopRule::component_targets. Default: one per
  // channel, at its own Student t critical value (infinite below 2 samples).
  virtual std::vector<ComponentError> component_errors(const JobState& state, double confidence) const;
  // Default: none, and progress shows channel 0.
  virtual std::optional<Headline> headline(const JobState&) const { return std::nullopt; }
  // Bytes the kernel itself holds while the job is in memory (a lighting job's scene:
  // meshes, acceleration structure, textures, environment map), an estimate counted
  // into the server's memory budget beside the job's state. Default: none.
  virtual uint64_t resident_bytes() const { return 0; }
};

// "N non-finite sample values were excluded", for kernels that count them; nullopt for 0.
// `counted_as_zero`: the kernel added them to sum channels as 0 instead (a sum keeps no
// per-sample count to leave them out of), and the warning says so.
std::optional<std::string> nonfinite_warning(uint64_t count, bool counted_as_zero = false);

}  // namespace tally
