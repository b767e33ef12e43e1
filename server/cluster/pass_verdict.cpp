#include "server/cluster/pass_verdict.hpp"

#include <fmt/format.h>

#include <algorithm>

namespace tally::cluster {

PassVerdict judge_pass(const PassState& st, size_t entries) {
  PassVerdict v;
  if (st.job_hash_read) {
    if (st.failed) {
      v.what = PassVerdict::fail;
      v.error = *st.failed;
    } else if (st.mismatch) {
      v.what = PassVerdict::fail;
      v.error = fmt::format(
          "non-determinism: two deliveries of the entry at block slot {} of a pass gave different results; the job "
          "cannot be trusted",
          *st.mismatch);
    } else if (!st.run) {
      v.what = PassVerdict::republish;  // Redis lost the job (restart, flush)
    }
  }
  if (v.what == PassVerdict::nothing) {
    if (st.entries_stored && static_cast<size_t>(*st.entries_stored) >= entries) {
      v.what = PassVerdict::merge;
    } else if (st.stream_exists && !*st.stream_exists) {
      v.what = PassVerdict::republish;
    }
  }
  return v;
}

ExecutorStats::JobBlocks blocks_in_flight(const PassFlight& f, uint64_t n, uint64_t k) {
  ExecutorStats::JobBlocks b;
  b.in_flight = std::min<uint64_t>(n - std::min<uint64_t>(n, f.blocks_done), f.entries_pending * k);
  b.redelivered = f.redelivered;
  b.pending = n > f.blocks_done + b.in_flight ? n - f.blocks_done - b.in_flight : 0;
  return b;
}

std::optional<std::string> crash_loop(const PassFlight& f, unsigned max_failures) {
  for (const PendingDelivery& d : f.oldest) {
    if (static_cast<uint64_t>(d.deliveries) > static_cast<uint64_t>(max_failures) + 1) {
      return fmt::format("an entry of blocks was delivered {} times and no worker finished it (last held by {}): the "
                         "workers crash or stall on it",
                         d.deliveries, d.consumer);
    }
  }
  return std::nullopt;
}

}  // namespace tally::cluster
