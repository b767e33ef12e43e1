#include "common/engine/counters.hpp"

namespace tally {

std::string_view counter_name(Counter c) {
  switch (c) {
    case Counter::evaluations: return "evaluations";
    case Counter::nonfinite: return "nonfinite";
    case Counter::rejection_attempts: return "rejection_attempts";
    case Counter::rejection_accepts: return "rejection_accepts";
    case Counter::rejection_failures: return "rejection_failures";
    case Counter::camera_rays: return "camera_rays";
    case Counter::shadow_rays: return "shadow_rays";
    case Counter::bounce_rays: return "bounce_rays";
    case Counter::sky_lookups: return "sky_lookups";
    case Counter::emission_lookups: return "emission_lookups";
    case Counter::light_samples: return "light_samples";
    case Counter::bsdf_samples: return "bsdf_samples";
    case Counter::specular_events: return "specular_events";
    case Counter::roulette_terminations: return "roulette_terminations";
    case Counter::kCount: break;
  }
  return "unknown";
}

nlohmann::json Counters::to_json() const {
  nlohmann::json j = nlohmann::json::object();
  for (size_t i = 0; i < values.size(); ++i) {
    if (values[i] != 0) j[std::string(counter_name(static_cast<Counter>(i)))] = values[i];
  }
  return j;
}

}  // namespace tally
