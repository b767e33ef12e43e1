#include "common/spec/stop_rule_json.hpp"

#include <fmt/format.h>

#include "common/engine/component_targets.hpp"

namespace tally {

namespace {

// One list of "component_targets": a number in [lo, hi] or null (0: the job-wide target).
std::vector<double> read_target_list(SpecReader& targets, std::string_view key, size_t max_components, double lo,
                                     double hi) {
  if (!targets.has(key)) return {};
  const nlohmann::json& v = targets.at(key);
  const std::string p = targets.pointer_of(key);
  if (!v.is_array()) throw SpecError(p, fmt::format("must be an array, got {}", json_type_name(v)));
  if (v.empty() || v.size() > max_components) {
    throw SpecError(p, fmt::format("must have 1 to {} entries (one per component), got {}", max_components, v.size()));
  }
  std::vector<double> out(v.size(), 0.0);
  for (size_t c = 0; c < v.size(); ++c) {
    if (!v[c].is_null()) out[c] = spec_number(v[c], json_pointer_append(p, c), lo, hi);
  }
  return out;
}

std::shared_ptr<const ComponentTargets> read_component_targets(SpecReader& stop, const JobLimits& limits) {
  SpecReader t = stop.object("component_targets");
  auto out = std::make_shared<ComponentTargets>();
  out->abs_error = read_target_list(t, "abs_error", limits.max_components, 1e-300, 1e300);
  out->rel_error = read_target_list(t, "rel_error", limits.max_components, 1e-12, 1e3);
  t.finish();
  if (out->abs_error.empty() && out->rel_error.empty()) {
    throw SpecError(t.pointer(), "needs abs_error or rel_error (one entry per component)");
  }
  if (!out->abs_error.empty() && !out->rel_error.empty() && out->abs_error.size() != out->rel_error.size()) {
    throw SpecError(t.pointer_of("rel_error"), fmt::format("has {} entries; abs_error has {}", out->rel_error.size(),
                                                           out->abs_error.size()));
  }
  return out;
}

// Every component needs a target: its own entry or the job-wide one.
void check_every_component_has_a_target(const StopRule& r, const std::string& pointer, std::string_view why) {
  const ComponentTargets& t = *r.component_targets;
  const size_t m = std::max(t.abs_error.size(), t.rel_error.size());
  for (size_t c = 0; c < m; ++c) {
    if (component_abs_target(r, c) == 0.0 && component_rel_target(r, c) == 0.0) {
      throw SpecError(pointer, fmt::format("component {} has no error target: its entries are null and the rule "
                                           "has no job-wide abs_error or rel_error{}",
                                           c, why));
    }
  }
}

StopRule read_rule(SpecReader& stop, const JobLimits& limits, const StopRule* keep, uint64_t min_samples_floor) {
  StopRule r;
  r.max_samples = stop.integer_or("max_samples", 0, 1, limits.max_samples);
  r.time_budget_s = stop.number_or("time_budget_s", 0.0, 1e-3, limits.max_seconds);
  r.abs_error = stop.number_or("abs_error", 0.0, 1e-300, 1e300);
  r.rel_error = stop.number_or("rel_error", 0.0, 1e-12, 1e3);
  if (keep) {
    r.confidence = keep->confidence;
    r.min_samples = keep->min_samples;
    r.component_targets = keep->component_targets;
    if (stop.has("component_targets")) {
      throw SpecError(stop.pointer_of("component_targets"),
                      "a job keeps its component targets; extend sets the job-wide ones");
    }
  } else {
    r.confidence = stop.number_or("confidence", 0.95, 0.5, 0.999999);
    r.min_samples = stop.integer_or("min_samples", 1000, min_samples_floor, limits.max_samples);
    if (stop.has("component_targets")) r.component_targets = read_component_targets(stop, limits);
  }
  stop.finish();
  if (r.component_targets) {
    // On extend the kept targets are not the body's to fix: name the job-wide target the
    // body must set (the one the job had, else rel_error).
    check_every_component_has_a_target(
        r, keep ? stop.pointer_of(keep->abs_error > 0.0 && keep->rel_error == 0.0 ? "abs_error" : "rel_error")
                : stop.pointer_of("component_targets"),
        keep ? " (extend keeps the job's component targets and replaces its job-wide ones)" : "");
  }
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
  if (r.component_targets) {
    auto list = [](const std::vector<double>& v) {
      nlohmann::json a = nlohmann::json::array();
      for (double x : v) a.push_back(x > 0.0 ? nlohmann::json(x) : nlohmann::json(nullptr));
      return a;
    };
    nlohmann::json& t = j["component_targets"];
    t = nlohmann::json::object();
    if (!r.component_targets->abs_error.empty()) t["abs_error"] = list(r.component_targets->abs_error);
    if (!r.component_targets->rel_error.empty()) t["rel_error"] = list(r.component_targets->rel_error);
  }
  return j;
}

}  // namespace tally
