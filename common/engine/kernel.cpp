#include "common/engine/kernel.hpp"

#include <algorithm>
#include <cmath>
#include <fmt/format.h>
#include <numeric>

#include "common/engine/channel_summary.hpp"
#include "common/engine/check.hpp"

#include "common/engine/job_state.hpp"
#include "common/stats/confidence.hpp"

namespace tally {

std::vector<ResultGroup> result_groups(std::span<const Block> blocks, uint64_t group_blocks) {
  const uint64_t g = std::max<uint64_t>(1, group_blocks);
  std::vector<ResultGroup> out;
  for (size_t i = 0; i < blocks.size(); ++i) {
    if (out.empty() || out.back().count >= g || blocks[i].partition != blocks[out.back().first].partition) {
      out.push_back({i, 0});
    }
    out.back().count++;
  }
  return out;
}

void combine_results(BlockResult& acc, const BlockResult& next) {
  TALLY_CHECK_EQ(acc.first_channel, next.first_channel);
  TALLY_CHECK_EQ(acc.tallies.size(), next.tallies.size());
  TALLY_CHECK_MSG(acc.aux.empty() && next.aux.empty(), "results with kernel accumulators (aux) are never combined");
  for (size_t c = 0; c < acc.tallies.size(); ++c) acc.tallies[c].merge(next.tallies[c]);
  TALLY_CHECK_EQ(acc.first_sum, next.first_sum);
  TALLY_CHECK_EQ(acc.sums.size(), next.sums.size());
  for (size_t c = 0; c < acc.sums.size(); ++c) acc.sums[c] += next.sums[c];
  acc.counters.merge(next.counters);
  acc.tail.merge(next.tail);
  acc.weights.merge(next.weights);
  if (!acc.fault && next.fault) acc.fault = next.fault;
}

std::vector<BlockResult> combine_groups(std::vector<BlockResult>&& per_block, std::span<const ResultGroup> groups,
                                        std::span<const uint8_t> folded) {
  TALLY_CHECK_MSG(folded.empty() || folded.size() == per_block.size(), "{} folded flags for {} blocks", folded.size(),
                  per_block.size());
  size_t covered = 0;
  for (const ResultGroup& g : groups) covered += g.count;
  TALLY_CHECK_MSG(covered == per_block.size(), "{} result groups cover {} blocks, the pass has {}", groups.size(), covered,
                  per_block.size());
  if (groups.size() == per_block.size()) return std::move(per_block);  // every group is one block
  std::vector<BlockResult> out;
  out.reserve(groups.size());
  for (const ResultGroup& g : groups) {
    TALLY_CHECK_LE(g.first + g.count, per_block.size());
    out.push_back(std::move(per_block[g.first]));
    for (size_t i = g.first + 1; i < g.first + g.count; ++i) {
      if (!folded.empty() && folded[i]) continue;
      combine_results(out.back(), per_block[i]);
    }
  }
  return out;
}

std::vector<uint32_t> Kernel::active_partitions(const JobState&) const {
  std::vector<uint32_t> all(partition_count());
  std::iota(all.begin(), all.end(), 0u);
  return all;
}

ErrorSummary Kernel::error_summary(const JobState& state, double confidence) const {
  return worst_channel_summary(state.channels, confidence);
}

std::vector<ComponentError> Kernel::component_errors(const JobState& state, double confidence) const {
  return channel_errors(state.channels, confidence);
}

std::vector<ComponentError> channel_errors(std::span<const Tally> channels, double confidence) {
  std::vector<ComponentError> out;
  out.reserve(channels.size());
  for (const Tally& t : channels) {
    const double half = t.n < 2 ? std::numeric_limits<double>::infinity()
                                : critical_value(confidence, t.n) * std::sqrt(t.variance()) /
                                      std::sqrt(static_cast<double>(t.n));
    out.push_back({half, t.mean});
  }
  return out;
}

ErrorSummary worst_channel_summary(std::span<const Tally> channels, double confidence) {
  ErrorSummary worst;
  bool any = false;
  for (const Tally& t : channels) {
    if (t.n < 2) {
      return {std::numeric_limits<double>::infinity(), std::numeric_limits<double>::infinity(),
              std::numeric_limits<double>::quiet_NaN(), t.mean};
    }
    const double z = critical_value(confidence, t.n);
    const double sigma = std::sqrt(t.variance());
    const double half = z * sigma / std::sqrt(static_cast<double>(t.n));
    const double rel = t.mean != 0.0 ? half / std::fabs(t.mean)
                                     : (half == 0.0 ? 0.0 : std::numeric_limits<double>::infinity());
    if (!any || half > worst.abs_error) {
      worst.abs_error = half;
      worst.sigma = sigma;
      worst.mean = t.mean;
    }
    if (!any || rel > worst.rel_error) worst.rel_error = rel;
    any = true;
  }
  if (!any) {
    return {std::numeric_limits<double>::infinity(), std::numeric_limits<double>::infinity(),
            std::numeric_limits<double>::quiet_NaN(), 0.0};
  }
  return worst;
}

std::optional<std::string> nonfinite_warning(uint64_t count, bool counted_as_zero) {
  if (count == 0) return std::nullopt;
  if (counted_as_zero) return fmt::format("{} non-finite sample values were counted as 0", count);
  return fmt::format("{} non-finite sample values were excluded", count);
}

}  // namespace tally
