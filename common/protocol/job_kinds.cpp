#include "common/protocol/job_kinds.hpp"

#include <fmt/format.h>

#include <optional>
#include <string>
#include <string_view>

#include "common/integrate/integration_job.hpp"
#include "common/integrate/integration_spec.hpp"
#include "common/lighting/lighting_job.hpp"
#include "common/lighting/lighting_spec.hpp"
#include "common/protocol/integration_json.hpp"
#include "common/protocol/lighting_json.hpp"
#include "common/spec/spec_reader.hpp"

namespace tally {

using nlohmann::json;

namespace {

struct JobKind {
  std::string_view name;
  std::unique_ptr<JobDefinition> (*compile)(const json& spec, const JobLimits& limits);
  // nullopt: `job` is not of this kind.
  std::optional<json> (*plan)(const JobDefinition& job);
  std::optional<json> (*result)(const JobDefinition& job, const JobRunner& runner);
  std::optional<json> (*progress)(const JobDefinition& job, const JobRunner& runner);
  // A stored spec of this kind as the engine of a results version read it (spec_as_of).
  json (*as_of)(json spec, uint32_t results_version);
};

// What a kind without progress fields adds to progress events.
json no_progress(const JobDefinition&, const JobRunner&) { return json::object(); }
// A kind whose defaults never changed reads its stored specs as they are.
json same_spec(json spec, uint32_t) { return spec; }

// One entry from the kind's job class, its spec reader and its views.
template <class Job, auto Compile, auto PlanView, auto ResultView, auto ProgressView = no_progress,
          auto AsOf = same_spec>
constexpr JobKind kind(std::string_view name) {
  return {name,
          [](const json& spec, const JobLimits& limits) -> std::unique_ptr<JobDefinition> {
            return Compile(spec, limits);
          },
          [](const JobDefinition& job) -> std::optional<json> {
            if (const auto* j = dynamic_cast<const Job*>(&job)) return PlanView(j->plan());
            return std::nullopt;
          },
          [](const JobDefinition& job, const JobRunner& runner) -> std::optional<json> {
            if (const auto* j = dynamic_cast<const Job*>(&job)) return ResultView(j->result(runner));
            return std::nullopt;
          },
          [](const JobDefinition& job, const JobRunner& runner) -> std::optional<json> {
            if (const auto* j = dynamic_cast<const Job*>(&job)) return ProgressView(*j, runner);
            return std::nullopt;
          },
          [](json spec, uint32_t results_version) { return AsOf(std::move(spec), results_version); }};
}

// The job kinds. A new kind: one line here.
constexpr JobKind kKinds[] = {
    kind<IntegrationJob, compile_integration_job, integration_plan_json, integration_result_json,
         integration_progress_json>("integrate"),
    kind<LightingJob, compile_lighting_job, lighting_plan_json, lighting_result_json, no_progress,
         lighting_spec_as_of>("lighting"),
};

// "a, b, c" (sep ", ") or "\"a\", \"b\" or \"c\"" (quoted, last " or ").
std::string names_list(bool quoted) {
  std::string out;
  const size_t n = std::size(kKinds);
  for (size_t i = 0; i < n; ++i) {
    if (i > 0) out += quoted ? (i + 1 == n ? " or " : ", ") : ", ";
    out += quoted ? fmt::format("\"{}\"", kKinds[i].name) : std::string(kKinds[i].name);
  }
  return out;
}

}  // namespace

std::unique_ptr<JobDefinition> compile_job(const json& spec, const JobLimits& limits) {
  if (!spec.is_object()) {
    throw SpecError("", fmt::format("a job spec must be a JSON object, got {}", json_type_name(spec)));
  }
  const auto it = spec.find("kind");
  if (it == spec.end()) throw SpecError("/kind", fmt::format("is required ({})", names_list(true)));
  if (!it->is_string()) throw SpecError("/kind", "must be a string");
  const std::string& name = it->get_ref<const std::string&>();
  for (const JobKind& k : kKinds) {
    if (k.name == name) return k.compile(spec, limits);
  }
  throw SpecError("/kind", fmt::format("must be one of {}; got \"{}\"", names_list(false), name));
}

json spec_as_of(const json& spec, uint32_t results_version) {
  if (!spec.is_object()) return spec;
  const auto it = spec.find("kind");
  if (it == spec.end() || !it->is_string()) return spec;
  for (const JobKind& k : kKinds) {
    if (k.name == it->get_ref<const std::string&>()) return k.as_of(spec, results_version);
  }
  return spec;
}

json kind_progress_json(const JobDefinition& job, const JobRunner& runner) {
  for (const JobKind& k : kKinds) {
    if (auto j = k.progress(job, runner)) return std::move(*j);
  }
  return json::object();
}

json plan_json(const JobDefinition& job) {
  for (const JobKind& k : kKinds) {
    if (auto j = k.plan(job)) return std::move(*j);
  }
  return {{"kind", std::string(job.kind())}};
}

json kind_result_json(const JobDefinition& job, const JobRunner& runner) {
  for (const JobKind& k : kKinds) {
    if (auto j = k.result(job, runner)) return std::move(*j);
  }
  return json::object();
}

}  // namespace tally
