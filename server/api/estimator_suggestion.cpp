#include "server/api/estimator_suggestion.hpp"

#include <cmath>
#include <limits>

#include "common/protocol/job_kinds.hpp"

namespace tally {

using nlohmann::json;

std::optional<json> estimator_suggestion(const json& spec, const JobDefinition& def, const json& prediction,
                                         const CompileSpec& compile) {
  if (def.kind() != "integrate" || !spec.is_object() || spec.contains("estimator")) return std::nullopt;
  const json plan = plan_json(def);
  // Scalar integrands only: a vector one's pilot evaluates every component at ~237,000
  // points (a 10,000-component job: seconds of CPU), too much for validate to run unasked.
  if (plan.value("estimator", json::object()).contains("components")) return std::nullopt;
  json with_auto = spec;
  with_auto["estimator"] = {{"type", "auto"}};
  const json chosen_plan = plan_json(*compile(with_auto)).at("estimator");
  const json& a = chosen_plan.at("auto");
  const json& cands = a.at("candidates");
  const json& chosen = cands.at(a.at("chosen").get<size_t>());
  if (chosen.at("estimator") == "uniform") return std::nullopt;
  double default_evals = std::numeric_limits<double>::quiet_NaN();
  for (const json& c : cands) {
    if (c.at("estimator") == "uniform" && c.at("predicted_evaluations").is_number()) {
      default_evals = c["predicted_evaluations"].get<double>();
    }
  }
  const double evals = chosen.at("predicted_evaluations").is_number() ? chosen["predicted_evaluations"].get<double>() : std::numeric_limits<double>::quiet_NaN();
  json would = {{"estimator", chosen.at("estimator")}, {"points_per_sample", chosen.at("points_per_sample")}};
  if (chosen.contains("periodize")) would["periodize"] = chosen["periodize"];
  json out = {{"estimator", {{"type", "auto"}}},
              {"would_choose", would},
              {"predicted_evaluations", std::isfinite(evals) ? json(evals) : json(nullptr)},
              {"default_predicted_evaluations", std::isfinite(default_evals) ? json(default_evals) : json(nullptr)},
              {"reason", a.at("reason")}};
  const double ratio = default_evals / evals;
  out["fewer_evaluations"] = std::isfinite(ratio) ? json(ratio) : json(nullptr);
  // The same cost per evaluation (the pilot's rate) at the suggested count: an estimate.
  if (std::isfinite(ratio) && ratio > 0 && prediction.is_object() && prediction.value("stops_by", "") == "error_target" &&
      prediction.value("seconds", json()).is_number()) {
    out["predicted_seconds"] = prediction["seconds"].get<double>() / ratio;
  }
  return out;
}

}  // namespace tally
