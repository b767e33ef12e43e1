#include "common/lighting/lighting_counters.hpp"

#include "common/engine/job_state.hpp"
#include "common/engine/kernel.hpp"

namespace tally {

namespace {
constexpr std::string_view kNames[] = {
    "evaluations",      "nonfinite",     "camera_rays",  "shadow_rays",     "bounce_rays",          "sky_lookups",
    "emission_lookups", "light_samples", "bsdf_samples", "specular_events", "roulette_terminations"};
static_assert(std::size(kNames) == static_cast<size_t>(LightingCounter::kCount));
}  // namespace

std::span<const std::string_view> lighting_counter_names() { return kNames; }

std::vector<std::string> lighting_counter_warnings(const JobState& state) {
  std::vector<std::string> w;
  // An image with replicates keeps sum channels, where such a sample counts as 0
  // (image_kernel.hpp); tallies leave it out.
  if (auto nf = nonfinite_warning(state.counters[LightingCounter::nonfinite], !state.sums.empty())) {
    w.push_back(std::move(*nf));
  }
  return w;
}

}  // namespace tally
