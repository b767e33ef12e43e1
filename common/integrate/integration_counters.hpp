#pragma once
// The event counters of integration kernels (Kernel::counter_names) and the warnings
// they imply (Kernel::warnings): rejection sampling that rarely accepts, samples dropped
// at the attempt cap, non-finite values.
#include <cstdint>
#include <span>
#include <string>
#include <string_view>
#include <vector>

namespace tally {

struct JobState;

enum class IntegrationCounter : uint8_t {
  evaluations,         // integrand evaluations
  nonfinite,           // NaN/Inf sample values (counted, never merged)
  rejection_attempts,  // proposals drawn by rejection sampling
  rejection_accepts,   // proposals accepted
  rejection_failures,  // samples abandoned at the attempt cap
  kCount
};

std::span<const std::string_view> integration_counter_names();
std::vector<std::string> integration_counter_warnings(const JobState& state);

}  // namespace tally
