#pragma once
// Steven G. Johnson's cubature (Debian libcubature-dev): h-adaptive (hcubature,
// Genz-Malik rules on recursively split boxes) and p-adaptive (pcubature, nested
// tensor Clenshaw-Curtis) deterministic cubature, driven to the same relative target
// as the Monte Carlo peers. Their `err` is an error *estimate*, not a confidence
// interval; the study records it in the half-width column and counts it the same way.
#include "bench/peers/gsl_peers.hpp"

namespace tally::peers {

enum class CubatureMethod { h, p };
const char* cubature_method_name(CubatureMethod m);

// Integrates g over [0,1]^d until err <= rel_half_width * |val| or the caps (the
// evaluation cap is passed as maxEval; the time cap stops the integrand).
PeerResult run_cubature(CubatureMethod m, GenzScalar g, const Target& t);

}  // namespace tally::peers
