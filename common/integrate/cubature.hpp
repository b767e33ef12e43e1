#pragma once
// Adaptive deterministic cubature (Steven G. Johnson's cubature library, Debian
// libcubature-dev): `hcubature_v` (h-adaptive: a degree-7 Genz-Malik rule on boxes
// split recursively where the error is largest) or `pcubature_v` (p-adaptive nested
// Clenshaw-Curtis). The whole rule runs in one block of one pass (the library keeps
// its region heap in memory, so it cannot be split across blocks or checkpointed);
// the block is bounded by an evaluation cap, so cancel and shutdown act within about
// a second. The result is deterministic: the same bits for any thread or worker count.
//
// What it reports is the library's *error estimate* (the difference between the rule
// and an embedded lower-degree rule, summed over regions), not a confidence interval:
// it can be wrong for integrands with features the rules do not resolve (jumps, narrow
// peaks between nodes). Channels: c = the integral of component c, m + c = its error
// estimate (one "sample" each).
#include <cstdint>
#include <memory>

#include "common/engine/job_state.hpp"
#include "common/engine/kernel.hpp"
#include "common/integrate/estimators.hpp"

namespace tally {

// Dimensions beyond this make the rules' point counts (2^d + 2d^2 + 2d + 1 per box for
// hcubature) too large for an adaptive split to pay off.
inline constexpr size_t kMaxCubatureDimensions = 8;
// One block's evaluations (~0.1-0.5 s for a cheap integrand): keeps cancel prompt.
inline constexpr uint64_t kMaxCubatureEvaluations = uint64_t{1} << 22;

struct CubatureOptions {
  bool p_adaptive = false;         // false: hcubature, true: pcubature
  uint64_t max_evaluations = uint64_t{1} << 20;
  double abs_error = 0.0;          // targets (0: none); it stops when either is met
  double rel_error = 0.0;
};

std::shared_ptr<const Kernel> make_cubature_kernel(IntegrationProblem p, CubatureOptions o);

}  // namespace tally
