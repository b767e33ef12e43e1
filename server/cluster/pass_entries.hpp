#pragma once
// How the coordinator cuts a pass into stream entries, and checks the results an entry
// comes back with. Pure functions over PassWork: no Redis here (docs/cluster.md, "How it
// works").
#include <cstddef>
#include <set>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "server/cluster/cluster_store.hpp"
#include "server/executor/executor.hpp"

namespace tally::cluster {

// A pass cut into stream entries of whole result groups (PassWork::groups). Planned at
// its first publication and kept when it is published again, so a late result of an
// entry from before a reconnect covers exactly the blocks of an entry published after it.
struct EntryPlan {
  std::vector<std::pair<size_t, size_t>> entries;  // (first slot, blocks), in slot order
  // Entry e's results are groups [entry_groups[e], entry_groups[e + 1]), one each.
  std::vector<size_t> entry_groups;
  size_t group_blocks = 1;  // the group size the groups were cut with (result_groups)
  size_t entry_blocks = 1;  // blocks in the largest entry
  // The entry whose first slot is `first`, or npos.
  size_t entry_at(size_t first) const;
  // The result groups of entry e: [first, last).
  std::pair<size_t, size_t> groups_of(size_t e, size_t group_count) const;
  static constexpr size_t npos = static_cast<size_t>(-1);
};

// Entry sizes by guided self-scheduling: each entry takes 1/(2T) of what is left (T:
// `threads`, the live worker threads), at most ~20 ms and at least ~2 ms of work (from
// `block_seconds`, the workers' measured time per block; 0: unknown, one block), capped
// at `max_entry_blocks`. A pass with another planned after it (PassWork::followed) needs
// no small tail (workers go on with the next pass): its entries are equal, 1/(2T) of
// the pass. Entries end where a result group ends. Checks (TALLY_CHECK) that the pass's
// groups are result_groups(blocks, g) for their largest size g, which is what workers cut.
EntryPlan plan_entries(const PassWork& pass, size_t threads, double block_seconds, size_t max_entry_blocks,
                       const std::string& job_id);

// What publishing the pass sends: its entries but those whose first slot is in
// `stored` (a republish after a reconnect), whose blocks are added to `stored_blocks`.
PassPublication publication(const PassWork& pass, const EntryPlan& plan, const std::set<size_t>& stored,
                            size_t& stored_blocks);

// Decodes the stored results of entry `e` and checks them (one per result group, each
// naming its group's first block, no tally counting more samples than the group's
// blocks planned); appends them to `out`. Returns an error that fails
// the job, else "".
std::string decode_entry(const PassWork& pass, const EntryPlan& plan, size_t e, std::string_view bytes,
                         std::vector<BlockResult>& out);

}  // namespace tally::cluster
