#include "server/jobs/spec_compile.hpp"

#include <fmt/format.h>

#include <algorithm>

#include "common/spec/spec_reader.hpp"

namespace tally {

std::unique_ptr<JobDefinition> compile_within_budget(const JobCompiler& compiler, const nlohmann::json& spec,
                                                     const JobLimits& limits, const Admission& admission) {
  std::unique_ptr<JobDefinition> def = compiler(spec, limits);  // throws SpecError
  const std::optional<std::string> why = admission.over_budget(Admission::memory_bytes(*def));
  if (!why) return def;
  // The kind's own state limit names the field: compile again with the state bytes
  // the budget leaves beside the kernel's resident bytes (the scene).
  JobLimits fit = limits;
  const uint64_t budget = admission.memory_budget(), resident = def->kernel()->resident_bytes();
  fit.max_state_bytes = std::min<uint64_t>(limits.max_state_bytes, budget > resident ? budget - resident : 0);
  try {
    compiler(spec, fit);
  } catch (const SpecError& e) {
    throw SpecError(e.pointer(), fmt::format("{}: {}", *why, e.detail()));
  }
  throw SpecError("", *why);
}

}  // namespace tally
