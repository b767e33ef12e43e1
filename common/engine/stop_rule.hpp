#pragma once
// When a job stops: whichever of its rules fires first, checked at pass boundaries.
#include <cstdint>
#include <memory>
#include <string_view>

namespace tally {

struct ComponentTargets;  // common/engine/component_targets.hpp

struct StopRule {
  uint64_t max_samples = 0;    // 0: none (the per-job cap still applies)
  double time_budget_s = 0.0;  // 0: none
  double abs_error = 0.0;      // target half-width at `confidence`; 0: none
  double rel_error = 0.0;      // target half-width / |mean|; 0: none
  double confidence = 0.95;
  uint64_t min_samples = 1000;  // error targets are not trusted before this
  // A vector job's own target per component (null: none). With it the error target is
  // met when every component meets its own (component_targets.hpp); shared because
  // rules are copied into snapshots and a list may hold 16,384 entries.
  std::shared_ptr<const ComponentTargets> component_targets;

  bool has_error_target() const { return abs_error > 0.0 || rel_error > 0.0 || component_targets != nullptr; }
};

enum class StopReason { none, max_samples, time_budget, error_target, cancelled, failed, sample_cap };

std::string_view stop_reason_name(StopReason r);

}  // namespace tally
