#pragma once
// What POST /v1/jobs/validate says about the estimator (docs/api.md "Validate"). An
// integration spec that names no estimator runs plain Monte Carlo, however smooth its
// integrand: the default stays so, since a default picked by a pilot would change the
// bits of every stored spec and its cached results. Instead, for such a spec with a
// scalar integrand, validate runs the automatic choice's pilot
// (common/integrate/auto_estimator.hpp) on the same spec and, when it would pick another
// estimator, names it with the integrand evaluations each needs to the job's target.
#include <functional>
#include <memory>
#include <optional>

#include <nlohmann/json.hpp>

#include "common/engine/job_definition.hpp"

namespace tally {

using CompileSpec = std::function<std::unique_ptr<JobDefinition>(const nlohmann::json& spec)>;

// {"estimator": {"type": "auto"}, "would_choose": {...}, "predicted_evaluations",
//  "default_predicted_evaluations", "fewer_evaluations", "predicted_seconds"?, "reason"}
// or nullopt (not an integration, an estimator named, a vector integrand, or plain
// Monte Carlo is as cheap as any). `def`: the spec compiled as given; `prediction`: the
// validate pilot's prediction (null or an object), scaled to the suggested estimator's
// evaluations when it stops by its error target. Throws what `compile` throws.
std::optional<nlohmann::json> estimator_suggestion(const nlohmann::json& spec, const JobDefinition& def,
                                                   const nlohmann::json& prediction, const CompileSpec& compile);

}  // namespace tally
