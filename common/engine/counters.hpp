#pragma once
// Event counters that prove what a job simulated (rays by kind, evaluations,
// rejected proposals...). Fixed slots, so adding them up in hot loops costs nothing.
#include <array>
#include <cstdint>
#include <nlohmann/json.hpp>
#include <string_view>

namespace tally {

enum class Counter : uint8_t {
  evaluations,         // integrand or path evaluations
  nonfinite,           // NaN/Inf sample values (counted, never merged)
  rejection_attempts,  // proposals drawn by rejection sampling
  rejection_accepts,   // proposals accepted
  rejection_failures,  // samples abandoned at the attempt cap
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

std::string_view counter_name(Counter c);

struct Counters {
  std::array<uint64_t, static_cast<size_t>(Counter::kCount)> values{};

  void add(Counter c, uint64_t k = 1) noexcept { values[static_cast<size_t>(c)] += k; }
  uint64_t operator[](Counter c) const noexcept { return values[static_cast<size_t>(c)]; }
  void merge(const Counters& o) noexcept {
    for (size_t i = 0; i < values.size(); ++i) values[i] += o.values[i];
  }
  nlohmann::json to_json() const;  // only the non-zero counters
  friend bool operator==(const Counters&, const Counters&) = default;
};

}  // namespace tally
