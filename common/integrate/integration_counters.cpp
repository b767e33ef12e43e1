#include "common/integrate/integration_counters.hpp"

#include <fmt/format.h>

#include "common/engine/job_state.hpp"
#include "common/engine/kernel.hpp"

namespace tally {

namespace {
constexpr std::string_view kNames[] = {"evaluations", "nonfinite", "rejection_attempts", "rejection_accepts",
                                       "rejection_failures"};
static_assert(std::size(kNames) == static_cast<size_t>(IntegrationCounter::kCount));
}  // namespace

std::span<const std::string_view> integration_counter_names() { return kNames; }

std::vector<std::string> integration_counter_warnings(const JobState& state) {
  std::vector<std::string> w;
  const Counters& c = state.counters;
  if (const uint64_t att = c[IntegrationCounter::rejection_attempts]; att > 0) {
    const double rate = static_cast<double>(c[IntegrationCounter::rejection_accepts]) / static_cast<double>(att);
    if (rate < 0.01) w.push_back(fmt::format("rejection sampling accepts only {:.3g} of proposals", rate));
  }
  if (const uint64_t f = c[IntegrationCounter::rejection_failures]; f > 0) {
    w.push_back(fmt::format("{} samples hit the rejection attempt cap and were dropped", f));
  }
  if (auto nf = nonfinite_warning(c[IntegrationCounter::nonfinite])) w.push_back(std::move(*nf));
  return w;
}

}  // namespace tally
