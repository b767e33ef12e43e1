#include "common/spec/stop_rule_json.hpp"

#include <fmt/format.h>

namespace tally {

namespace {

StopRule read_rule(SpecReader& stop, const JobLimits& limits, const StopRule* keep, uint64_t min_samples_floor) {
  StopRule r;
  r.max_samples = stop.integer_or("max_samples", 0, 1, limits.max_samples);
  r.time_budget_s = stop.number_or("time_budget_s", 0.0, 1e-3, limits.max_seconds);
  r.abs_error = stop.number_or("abs_error", 0.0, 1e-300, 1e300);
  r.rel_error = stop.number_or("rel_error", 0.0, 1e-12, 1e3);
  if (keep) {
    r.confidence = keep->confidence;
    r.min_samples = keep->min_samples;
  } else {
    r.confidence = stop.number_or("confidence", 0.95, 0.5, 0.999999);
    r.min_samples = stop.integer_or("min_samples", 1000, min_samples_floor, limits.max_samples);
  }
  stop.finish();
  if (r.max_samples == 0 && r.time_budget_s == 0.0 && !r.has_error_target()) {
    throw SpecError(stop.pointer(),
                    "needs at least one of max_samples, time_budget_s, abs_error, rel_error");
  }
  return r;
}

}  // namespace

StopRule parse_stop_rule(SpecReader& stop, const JobLimits& limits, const StopRule* keep) {
  return read_rule(stop, limits, keep, 2);
}

StopRule parse_stored_stop_rule(SpecReader& stop, const JobLimits& limits) { return read_rule(stop, limits, nullptr, 1); }

nlohmann::json stop_rule_to_json(const StopRule& r) {
  nlohmann::json j;
  if (r.max_samples > 0) j["max_samples"] = r.max_samples;
  if (r.time_budget_s > 0) j["time_budget_s"] = r.time_budget_s;
  if (r.abs_error > 0) j["abs_error"] = r.abs_error;
  if (r.rel_error > 0) j["rel_error"] = r.rel_error;
  j["confidence"] = r.confidence;
  j["min_samples"] = r.min_samples;
  return j;
}

}  // namespace tally
