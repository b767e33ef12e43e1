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
  // The kind's own channel limit names the field: compile again with the channels
  // the budget allows.
  JobLimits fit = limits;
  fit.max_channels = std::min<size_t>(limits.max_channels, admission.memory_budget() / (2 * sizeof(Tally)));
  try {
    compiler(spec, fit);
  } catch (const SpecError& e) {
    throw SpecError(e.pointer(), fmt::format("{}: {}", *why, e.detail()));
  }
  throw SpecError("", *why);
}

}  // namespace tally
