#include "common/engine/stop_rule.hpp"

namespace tally {

std::string_view stop_reason_name(StopReason r) {
  switch (r) {
    case StopReason::none: return "none";
    case StopReason::max_samples: return "max_samples";
    case StopReason::time_budget: return "time_budget";
    case StopReason::error_target: return "error_target";
    case StopReason::cancelled: return "cancelled";
    case StopReason::failed: return "failed";
    case StopReason::sample_cap: return "job_cap";
  }
  return "unknown";
}

}  // namespace tally
