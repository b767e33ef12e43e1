#pragma once
// Per-component error targets of a vector job (StopRule::component_targets): component c
// meets its target when its half-width is at most its abs_error or its half-width / |mean|
// at most its rel_error (the job-wide rule's "abs or rel", per component). An entry of 0
// (null in JSON) means the job-wide target applies. The job stops at its error target when
// every component meets its own. Two doubles per component at most; no pairs.
#include <cstddef>
#include <span>
#include <vector>

namespace tally {

struct StopRule;

struct ComponentTargets {
  std::vector<double> abs_error;  // empty, or one per component; 0: the rule's abs_error
  std::vector<double> rel_error;  // empty, or one per component; 0: the rule's rel_error
  bool operator==(const ComponentTargets&) const = default;
};

// One component's error as the stop rule reads it (Kernel::component_errors).
struct ComponentError {
  double half_width = 0.0;  // of the interval at the rule's confidence (or an error estimate)
  double mean = 0.0;
};

// Component c's own targets: its entry, else the rule's job-wide one (0: none).
double component_abs_target(const StopRule& rule, size_t c);
double component_rel_target(const StopRule& rule, size_t c);

// How far component c is from its own target: the smaller of half / abs_target and
// (half / |mean|) / rel_target over the targets it has; <= 1 meets. Infinite without a
// target, and NaN reads as infinite (an unknown error never meets).
double component_target_ratio(const StopRule& rule, size_t c, const ComponentError& e);

// Every component meets its own target (false for an empty list).
bool every_component_met(const StopRule& rule, std::span<const ComponentError> errors);

}  // namespace tally
