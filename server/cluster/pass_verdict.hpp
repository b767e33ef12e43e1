#pragma once
// What the coordinator concludes from a pass's state in Redis (cluster_store.hpp's
// probes): whether to merge it, fail its job or publish it again, and its blocks in
// flight. Pure functions, no Redis.
#include <optional>
#include <string>

#include "server/cluster/cluster_store.hpp"
#include "server/executor/executor.hpp"

namespace tally::cluster {

struct PassVerdict {
  enum What { nothing, merge, fail, republish } what = nothing;
  std::string error;  // fail: why
};
// `entries`: the pass's entries (a complete pass has a result for each).
PassVerdict judge_pass(const PassState& state, size_t entries);

// Blocks of a pass of `blocks` blocks, at most `entry_blocks` per entry: pending, in
// flight, redelivered.
ExecutorStats::JobBlocks blocks_in_flight(const PassFlight& flight, uint64_t blocks, uint64_t entry_blocks);

// An entry delivered more than max_failures + 1 times without a result: the workers
// that took it died or stalled each time (a crash on that block, not a thrown error).
// The job's error, or nullopt. One delivery more than --max-deliveries allows one stall.
std::optional<std::string> crash_loop(const PassFlight& flight, unsigned max_failures);

}  // namespace tally::cluster
