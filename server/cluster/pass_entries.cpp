#include "server/cluster/pass_entries.hpp"

#include <fmt/format.h>

#include <algorithm>

#include "common/engine/check.hpp"
#include "server/cluster/wire.hpp"

namespace tally::cluster {

size_t EntryPlan::entry_at(size_t first) const {
  auto it = std::lower_bound(entries.begin(), entries.end(), std::make_pair(first, size_t{0}));
  if (it == entries.end() || it->first != first) return npos;
  return static_cast<size_t>(it - entries.begin());
}

std::pair<size_t, size_t> EntryPlan::groups_of(size_t e, size_t group_count) const {
  return {entry_groups[e], e + 1 < entry_groups.size() ? entry_groups[e + 1] : group_count};
}

EntryPlan plan_entries(const PassWork& pass, size_t threads, double block_seconds, size_t max_entry_blocks,
                       const std::string& job_id) {
  size_t k_max = 1, k_min = 1;
  threads = std::max<size_t>(1, threads);
  if (block_seconds > 0) {
    k_max = static_cast<size_t>(std::clamp(0.02 / block_seconds, 1.0, 4096.0));
    k_min = static_cast<size_t>(std::clamp(0.002 / block_seconds, 1.0, 4096.0));
  }
  k_max = std::clamp<size_t>(k_max, 1, std::max<size_t>(1, max_entry_blocks));
  k_min = std::min(k_min, k_max);
  const std::vector<ResultGroup>& groups = pass.groups;
  const size_t n = pass.blocks.size();
  // The groups are the ones result_groups cuts with their largest size: a worker cuts
  // its entry's blocks the same way from that one number (the pass hash's "g").
  size_t g = 1, covered = 0;
  for (const ResultGroup& r : groups) {
    g = std::max(g, r.count);
    covered += r.count;
  }
  TALLY_CHECK_MSG(covered == n && result_groups(pass.blocks, g) == groups,
                  "pass {} of job {}: its result groups are not result_groups(blocks, {})", pass.pass, job_id, g);
  EntryPlan plan;
  plan.group_blocks = g;
  for (size_t gi = 0; gi < groups.size();) {
    const size_t first = groups[gi].first;
    const size_t left = n - first;
    const size_t share = pass.followed ? n : left;  // of the pass, or of what is left
    const size_t want = std::min(left, std::clamp((share + 2 * threads - 1) / (2 * threads), k_min, k_max));
    size_t k = 0;
    plan.entry_groups.push_back(gi);
    while (gi < groups.size() && (k == 0 || k + groups[gi].count <= want)) k += groups[gi++].count;
    plan.entries.emplace_back(first, k);
    plan.entry_blocks = std::max(plan.entry_blocks, k);
  }
  return plan;
}

PassPublication publication(const PassWork& pass, const EntryPlan& plan, const std::set<size_t>& stored,
                            size_t& stored_blocks) {
  PassPublication pub{pass.blocks.size(), plan.entries.size(), plan.group_blocks, pass.pass_input, {}};
  for (const auto& [first, count] : plan.entries) {
    if (stored.count(first)) {
      stored_blocks += count;
      continue;
    }
    std::string bytes;
    for (size_t i = first; i < first + count; ++i) bytes += encode_block(pass.blocks[i]);
    pub.new_entries.emplace_back(std::to_string(first), std::move(bytes));
  }
  return pub;
}

std::string decode_entry(const PassWork& pass, const EntryPlan& plan, size_t e, std::string_view bytes,
                         std::vector<BlockResult>& out) {
  const size_t first = plan.entries[e].first;
  const auto [g0, g1] = plan.groups_of(e, pass.groups.size());
  std::vector<BlockResult> res;
  try {
    res = decode_entry_results(bytes);
  } catch (const WireError& err) {
    return fmt::format("the results of the entry at block slot {} cannot be decoded: {}", first, err.what());
  }
  if (res.size() != g1 - g0) {
    return fmt::format("the entry at block slot {} has {} results, expected {} (one per result group)", first,
                       res.size(), g1 - g0);
  }
  for (size_t j = 0; j < res.size(); ++j) {
    const ResultGroup& g = pass.groups[g0 + j];
    const size_t slot = g.first;
    if (res[j].block_index != pass.blocks[slot].index) {
      return fmt::format("the result in slot {} belongs to block {}, expected {}", slot, res[j].block_index,
                         pass.blocks[slot].index);
    }
    // A sample adds to a tally at most once: no tally of the group counts more samples
    // than its blocks planned.
    uint64_t planned = 0;
    for (size_t b = g.first; b < g.first + g.count; ++b) planned += pass.blocks[b].sample_count;
    for (size_t t = 0; t < res[j].tallies.size(); ++t) {
      if (res[j].tallies[t].n > planned) {
        return fmt::format("the result of the group at block slot {} counts {} samples in channel {}, but its blocks "
                           "hold {}: the results were changed or a worker is broken",
                           slot, res[j].tallies[t].n, res[j].first_channel + t, planned);
      }
    }
  }
  for (auto& r : res) out.push_back(std::move(r));
  return {};
}

}  // namespace tally::cluster
