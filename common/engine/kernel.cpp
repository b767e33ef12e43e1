#include "common/engine/kernel.hpp"

#include <cmath>
#include <fmt/format.h>
#include <numeric>

#include "common/engine/job_state.hpp"
#include "common/stats/confidence.hpp"

namespace tally {

std::vector<uint32_t> Kernel::active_partitions(const JobState&) const {
  std::vector<uint32_t> all(partition_count());
  std::iota(all.begin(), all.end(), 0u);
  return all;
}

ErrorSummary Kernel::error_summary(const JobState& state, double confidence) const {
  ErrorSummary worst;
  bool any = false;
  for (const Tally& t : state.channels) {
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

std::optional<std::string> nonfinite_warning(uint64_t count) {
  if (count == 0) return std::nullopt;
  return fmt::format("{} non-finite sample values were excluded", count);
}

}  // namespace tally
