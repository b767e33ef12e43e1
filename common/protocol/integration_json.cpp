#include "common/protocol/integration_json.hpp"

#include <cmath>

#include "common/spec/stop_rule_json.hpp"

namespace tally {

using nlohmann::json;

namespace {
json finite_or_null(double v) { return std::isfinite(v) ? json(v) : json(nullptr); }

template <class T>
void put(json& j, const char* key, const std::optional<T>& v) {
  if (v) j[key] = *v;
}
}  // namespace

json integrand_json(const IntegrandInfo& info) {
  json j = json::object();
  if (!info.builtin.empty()) j["builtin"] = info.builtin;
  if (info.expression) j["expression"] = *info.expression;
  if (!info.expressions.empty()) j["expressions"] = info.expressions;
  if (!info.parameters.empty()) {
    json p = json::object();
    for (const auto& [name, values] : info.parameters) p[name] = values;
    j["parameters"] = std::move(p);
  }
  if (info.builtin == "genz") {
    if (info.families.empty()) {
      j["family"] = info.family;
    } else {
      j["families"] = info.families;
    }
    j["a"] = info.a;
    j["u"] = info.u;
  }
  return j;
}

json domain_json(const DomainInfo& info) {
  json j = {{"type", info.type}};
  if (!info.lower.empty()) {
    j["lower"] = info.lower;
    j["upper"] = info.upper;
  }
  if (!info.center.empty()) j["center"] = info.center;
  put(j, "radius", info.radius);
  put(j, "dimensions", info.dimensions);
  return j;
}

json auto_selection_json(const AutoSelection& a) {
  json cands = json::array();
  for (const AutoCandidate& c : a.candidates) {
    json pilot_sd = json::array();
    for (double sd : c.pilot_sd) pilot_sd.push_back(finite_or_null(sd));
    json e = {{"estimator", c.estimator},
              {"pilot_points", c.pilot_points},
              {"pilot_sd", pilot_sd},
              {"rate", c.rate},
              {"points_per_sample", c.points},
              {"predicted_evaluations", finite_or_null(c.predicted_evaluations)}};
    if (!c.periodize.empty()) e["periodize"] = c.periodize;
    if (a.components > 1) e["limiting_component"] = c.limiting_component;
    cands.push_back(std::move(e));
  }
  return {{"chosen", a.chosen},
          {"reason", a.reason},
          {"target_half_width", a.target_half_width},
          {"pilot_evaluations", a.pilot_evaluations},
          {"candidates", std::move(cands)}};
}

json estimator_plan_json(const EstimatorPlan& p) {
  json j = {{"type", p.type}};
  if (p.selection) j["auto"] = auto_selection_json(*p.selection);
  put(j, "components", p.components);
  if (p.density) {
    json d = {{"type", p.density->type}};
    if (!p.density->exponent.empty()) d["exponent"] = p.density->exponent;
    put(d, "cells", p.density->cells);
    j["density"] = d;
  }
  put(j, "strata_per_dim", p.strata_per_dim);
  put(j, "stratified_dims", p.stratified_dims);
  put(j, "points_per_sample", p.points_per_sample);
  put(j, "sequence", p.sequence);
  put(j, "scramble", p.scramble);
  put(j, "interlacing", p.interlacing);
  put(j, "construction", p.construction);
  put(j, "periodize", p.periodize);
  if (!p.generating_vector.empty()) j["generating_vector"] = p.generating_vector;
  if (!p.weights.empty()) j["weights"] = p.weights;
  put(j, "worst_case_error", p.worst_case_error);
  put(j, "bins", p.bins);
  put(j, "alpha", p.alpha);
  put(j, "warmup_passes", p.warmup_passes);
  put(j, "max_pass_samples", p.max_pass_samples);
  put(j, "combine", p.combine);
  put(j, "combination", p.combination);
  put(j, "steering", p.steering);
  put(j, "stratify", p.stratify);
  put(j, "beta", p.beta);
  put(j, "strata_per_axis", p.strata_per_axis);
  put(j, "stratification", p.stratification);
  put(j, "max_attempts", p.max_attempts);
  put(j, "rule", p.rule);
  put(j, "points_per_dim", p.points_per_dim);
  put(j, "points", p.points);
  put(j, "max_evaluations", p.max_evaluations);
  put(j, "error", p.error);
  return j;
}

json integration_plan_json(const IntegrationPlan& p) {
  return {{"kind", "integrate"},
          {"integrand", integrand_json(p.integrand)},
          {"domain", domain_json(p.domain)},
          {"estimator", estimator_plan_json(p.estimator)},
          {"dimensions", p.dimensions},
          {"measure", p.measure},
          {"stop", stop_rule_to_json(p.stop)},
          {"seed", p.seed}};
}

json components_summary_json(const ComponentsSummary& cs) {
  json sj = {{"count", cs.count},
             {"worst",
              {{"index", cs.worst},
               {"half_width", finite_or_null(cs.worst_half_width)},
               {"rel_half_width", finite_or_null(cs.worst_rel_half_width)}}}};
  if (cs.met) sj["met"] = *cs.met;
  if (cs.met && *cs.met < cs.count) {
    sj["unmet"] = {{"count", cs.count - *cs.met}, {"first", cs.unmet}};
  }
  return sj;
}

json integration_progress_json(const IntegrationJob& job, const JobRunner& runner) {
  if (job.plan().estimator.components.value_or(1) <= 1) return json::object();
  const IntegrationResult r = job.result(runner);
  if (!r.components_summary) return json::object();
  return {{"components", components_summary_json(*r.components_summary)}};
}

json integration_result_json(const IntegrationResult& r) {
  json j;
  j["integrand"] = integrand_json(r.integrand);
  j["domain"] = domain_json(r.domain);
  j["estimator"] = estimator_plan_json(r.estimator);
  j["evaluations"] = r.evaluations;
  j["sample_unit"] = r.sample_unit;
  if (r.error_estimate) j["error_estimate"] = finite_or_null(*r.error_estimate);
  if (!r.components.empty()) {
    json comps = json::array();
    for (const ComponentEstimate& c : r.components) {
      if (c.error_estimate) {  // cubature: a value and the rule's error estimate, no interval
        comps.push_back({{"mean", finite_or_null(c.mean)}, {"error_estimate", finite_or_null(*c.error_estimate)}});
      } else {
        comps.push_back({{"mean", c.mean}, {"std_error", finite_or_null(c.std_error)}, {"ci", {c.ci_lo, c.ci_hi}}});
      }
    }
    j["components"] = comps;
    if (r.components_summary) j["components_summary"] = components_summary_json(*r.components_summary);
    if (!r.covariance_of_means.empty()) {
      json rows = json::array();
      for (const auto& row : r.covariance_of_means) rows.push_back(row);
      j["covariance_of_means"] = rows;
    }
  }
  if (r.vegas) {
    const VegasSummary& v = *r.vegas;
    json its = json::array();
    for (const VegasIterationSummary& it : v.iterations) {
      its.push_back({{"n", it.n},
                     {"mean", it.mean},
                     {"std_error", it.std_error ? json(*it.std_error) : json(nullptr)},
                     {"warmup", it.warmup}});
    }
    j["vegas"] = {{"iterations", its},
                  {"used_iterations", v.used_iterations},
                  {"chi2_per_dof", finite_or_null(v.chi2_per_dof)},
                  {"p_value", v.p_value},
                  {"consistent", v.consistent},
                  {"error_scale", v.error_scale}};
    if (v.hypercubes) {
      j["vegas"]["strata_per_axis"] = *v.strata_per_axis;
      j["vegas"]["hypercubes"] = *v.hypercubes;
      j["vegas"]["next_allocation"] = {{"min", *v.next_allocation_min}, {"max", *v.next_allocation_max}};
    }
  }
  if (r.reference) {
    j["reference"] = *r.reference;
    j["error_vs_reference"] = r.error_vs_reference;
    put(j, "z_score", r.z_score);
  }
  return j;
}

}  // namespace tally
