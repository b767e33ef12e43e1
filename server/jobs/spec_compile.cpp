#include "server/jobs/spec_compile.hpp"

#include <fmt/format.h>

#include <algorithm>

#include "common/spec/state_limit_error.hpp"

namespace tally {

std::unique_ptr<JobDefinition> compile_within_budget(const JobCompiler& compiler, const nlohmann::json& spec,
                                                     const JobLimits& limits, const Admission& admission) {
  // The kind's own state limit is held to the budget as well: a state that could never
  // fit is refused by the spec reader, naming the field that makes it big.
  JobLimits fit = limits;
  const uint64_t budget = admission.memory_budget();
  if (budget != 0) fit.max_state_bytes = std::min(limits.max_state_bytes, budget);
  std::unique_ptr<JobDefinition> def;
  try {
    def = compiler(spec, fit);  // throws SpecError
  } catch (const StateLimitError& e) {
    if (fit.max_state_bytes == limits.max_state_bytes) throw;
    throw SpecError(e.pointer(), fmt::format("{}, the server's memory budget (--memory-budget)", e.detail()));
  }
  // The state fits the budget; with the scene beside it the job may still not.
  if (const std::optional<std::string> why = admission.over_budget(Admission::memory_bytes(*def))) {
    throw SpecError("", *why);
  }
  return def;
}

}  // namespace tally
