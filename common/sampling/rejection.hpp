#pragma once
// Rejection sampling with an attempt cap. The proposal draws its uniforms from the
// SampleRng sequentially (rng.next()), so one sample consumes a *variable* number of
// dimensions: give a rejection sampler its own SampleRng (stream or index) rather than
// sharing one whose later dimensions other code relies on.
// The cap turns "almost never accepts" into a counted failure (std::nullopt) instead of
// a hang; the stats let the engine report a tiny acceptance rate to the user.
#include <cstdint>
#include <optional>
#include <type_traits>
#include <utility>

#include "common/rng/counter_rng.hpp"

namespace tally {

struct RejectionStats {
  std::uint64_t attempts = 0;
  std::uint64_t accepted = 0;

  // accepted / attempts; 0 before any attempt (there is no evidence of acceptance yet).
  double acceptance_rate() const {
    return attempts == 0 ? 0.0 : static_cast<double>(accepted) / static_cast<double>(attempts);
  }
  RejectionStats& operator+=(const RejectionStats& o) {
    attempts += o.attempts;
    accepted += o.accepted;
    return *this;
  }
};

// propose(rng) returns std::optional<T>: a value when the candidate is accepted,
// std::nullopt when it is rejected. Returns the first accepted value, or std::nullopt
// after max_attempts rejections (the caller counts that failure).
template <class Propose>
auto rejection_sample(SampleRng& rng, std::uint64_t max_attempts, RejectionStats& stats,
                      Propose&& propose) -> std::invoke_result_t<Propose&, SampleRng&> {
  for (std::uint64_t i = 0; i < max_attempts; ++i) {
    ++stats.attempts;
    if (auto candidate = propose(rng)) {
      ++stats.accepted;
      return candidate;
    }
  }
  return std::nullopt;
}

}  // namespace tally
