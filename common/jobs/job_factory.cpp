#include "common/jobs/job_factory.hpp"

#include <fmt/format.h>

#include "common/integrate/integration_spec.hpp"
#include "common/protocol/spec_reader.hpp"
#include "common/lighting/lighting_spec.hpp"

namespace tally {

std::unique_ptr<JobDefinition> compile_job(const nlohmann::json& spec, const JobLimits& limits) {
  if (!spec.is_object()) {
    throw SpecError("", fmt::format("a job spec must be a JSON object, got {}", json_type_name(spec)));
  }
  const auto it = spec.find("kind");
  if (it == spec.end()) throw SpecError("/kind", "is required (\"integrate\" or \"lighting\")");
  if (!it->is_string()) throw SpecError("/kind", "must be a string");
  const std::string& kind = it->get_ref<const std::string&>();
  if (kind == "integrate") return compile_integration_job(spec, limits);
  if (kind == "lighting") return compile_lighting_job(spec, limits);
  throw SpecError("/kind", fmt::format("must be one of integrate, lighting; got \"{}\"", kind));
}

}  // namespace tally
