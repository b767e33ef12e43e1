#include "common/engine/component_targets.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "common/engine/stop_rule.hpp"

namespace tally {

namespace {

double entry_or(const std::vector<double>& v, size_t c, double fallback) {
  return c < v.size() && v[c] > 0.0 ? v[c] : fallback;
}

}  // namespace

double component_abs_target(const StopRule& rule, size_t c) {
  return rule.component_targets ? entry_or(rule.component_targets->abs_error, c, rule.abs_error) : rule.abs_error;
}

double component_rel_target(const StopRule& rule, size_t c) {
  return rule.component_targets ? entry_or(rule.component_targets->rel_error, c, rule.rel_error) : rule.rel_error;
}

double component_target_ratio(const StopRule& rule, size_t c, const ComponentError& e) {
  constexpr double kInf = std::numeric_limits<double>::infinity();
  const double half = std::fabs(e.half_width);
  double ratio = kInf;
  if (const double a = component_abs_target(rule, c); a > 0.0) ratio = std::min(ratio, half / a);
  if (const double r = component_rel_target(rule, c); r > 0.0) {
    const double rel = e.mean != 0.0 ? half / std::fabs(e.mean) : (half == 0.0 ? 0.0 : kInf);
    ratio = std::min(ratio, rel / r);
  }
  return std::isnan(ratio) ? kInf : ratio;
}

bool every_component_met(const StopRule& rule, std::span<const ComponentError> errors) {
  if (errors.empty()) return false;
  for (size_t c = 0; c < errors.size(); ++c) {
    if (!(component_target_ratio(rule, c, errors[c]) <= 1.0)) return false;
  }
  return true;
}

}  // namespace tally
