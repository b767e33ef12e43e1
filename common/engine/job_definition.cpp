#include "common/engine/job_definition.hpp"

#include <fmt/format.h>

namespace tally {

std::string JobDefinition::summary_line(const JobRunner& runner) const {
  const Estimate e = runner.estimate(0);
  return fmt::format("{:.10g} ± {:.3g} ({:g}% CI [{:.10g}, {:.10g}])", e.mean, e.std_error,
                     100.0 * e.confidence, e.ci_lo, e.ci_hi);
}

}  // namespace tally
