#pragma once
// The event counters of lighting kernels (Kernel::counter_names): rays and lookups by
// kind, which prove what the planner switched off (docs/lighting.md).
#include <cstdint>
#include <span>
#include <string>
#include <string_view>
#include <vector>

namespace tally {

struct JobState;

enum class LightingCounter : uint8_t {
  evaluations,  // path evaluations
  nonfinite,    // NaN/Inf sample values (counted, never merged)
  camera_rays,
  shadow_rays,
  bounce_rays,
  sky_lookups,
  emission_lookups,
  light_samples,
  bsdf_samples,
  specular_events,
  roulette_terminations,
  kCount
};

std::span<const std::string_view> lighting_counter_names();
// What the counters warn about (non-finite values).
std::vector<std::string> lighting_counter_warnings(const JobState& state);

}  // namespace tally
