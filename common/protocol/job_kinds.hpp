#pragma once
// Every job kind's JSON face, from one table (job_kinds.cpp): its name in specs, its spec
// reader (JSON -> a runnable job) and its views (the typed plan and result -> JSON).
// A new kind is one entry there plus its folder (common/<kind>/: spec reader, job,
// kernel) and its views (common/protocol/<kind>_json.cpp).
#include <memory>
#include <nlohmann/json.hpp>

#include "common/engine/job_definition.hpp"
#include "common/engine/job_runner.hpp"
#include "common/engine/limits.hpp"

namespace tally {

// Validates `spec` (throws SpecError with the JSON pointer of the first bad field)
// and compiles it with the reader of the kind spec["kind"] names.
std::unique_ptr<JobDefinition> compile_job(const nlohmann::json& spec, const JobLimits& limits);

// A stored spec as the engine of `results_version` read it: each default that changed
// since then is written in (by the kind's entry, e.g. lighting_spec_as_of), so the spec
// compiles to the layout of the state that version computed. Server recovery compiles this for a job with stored state: a job
// computed before an upgrade stays readable and resumes bit-identically. Anything else is
// returned unchanged (not an object, no "kind", the current version).
nlohmann::json spec_as_of(const nlohmann::json& spec, uint32_t results_version);

// The kind's plan document (status, validate, `tally run --json`) and result fields.
// A job of no registered kind (e.g. a test's fake job) shows {"kind": ...} as its plan
// and an empty result.
nlohmann::json plan_json(const JobDefinition& job);
nlohmann::json kind_result_json(const JobDefinition& job, const JobRunner& runner);
// What the kind adds to each progress event (e.g. a vector integrand's components
// summary); an empty object when nothing.
nlohmann::json kind_progress_json(const JobDefinition& job, const JobRunner& runner);

}  // namespace tally
