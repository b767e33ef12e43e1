#pragma once
// GSL's Monte Carlo integrators (plain, MISER, VEGAS) driven to a relative error
// target the way a careful user would: batches sized from the error so far (aimed at
// the predicted need with 10% headroom, at most doubling the total, like tally's own
// runner), independent batches pooled by their call counts (plain, MISER: weights
// fixed by n, so the pooled error sum n_i^2 sigma_i^2 / N^2 is exact), VEGAS after a
// discarded warm-up with its iterations accumulated and its chi^2/dof checked.
#include <cstdint>
#include <string>

#include "bench/peers/genz_scalar.hpp"

namespace tally::peers {

struct Target {
  double rel_half_width = 5e-4;  // stop when z * sigma <= this * |estimate|
  double z = 1.959963984540054;  // 95% two-sided normal
  uint64_t first_batch = 16384;
  uint64_t max_evaluations = uint64_t{1} << 25;
  double max_seconds = 1.0;
};

struct PeerResult {
  double estimate = 0.0;
  double half_width = 0.0;  // reported sigma * z
  double seconds = 0.0;
  uint64_t evaluations = 0;
  bool converged = false;  // its own stopping rule was met before the caps
  std::string note;
};

enum class GslMethod { plain, miser, vegas };
const char* gsl_method_name(GslMethod m);

// Integrates g over [0,1]^d; `seed` seeds GSL's mt19937.
PeerResult run_gsl(GslMethod m, GenzScalar g, const Target& t, unsigned long seed);

}  // namespace tally::peers
