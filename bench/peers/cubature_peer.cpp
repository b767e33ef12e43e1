#include "bench/peers/cubature_peer.hpp"

#include <cubature.h>

#include <chrono>
#include <cmath>
#include <vector>

namespace tally::peers {

namespace {

using Clock = std::chrono::steady_clock;

struct Data {
  GenzScalar g;
  Clock::time_point t0;
  double max_seconds = 1.0;
  bool timed_out = false;
};

int integrand(unsigned ndim, const double* x, void* p, unsigned, double* fval) {
  auto* d = static_cast<Data*>(p);
  // Check the clock every 4096 evaluations: returning nonzero stops cubature.
  if ((*d->g.evaluations & 4095u) == 0 &&
      std::chrono::duration<double>(Clock::now() - d->t0).count() >= d->max_seconds) {
    d->timed_out = true;
    return 1;
  }
  fval[0] = genz_scalar(x, ndim, d->g);
  return 0;
}

}  // namespace

const char* cubature_method_name(CubatureMethod m) { return m == CubatureMethod::h ? "hcubature" : "pcubature"; }

PeerResult run_cubature(CubatureMethod m, GenzScalar g, const Target& t) {
  Data data;
  unsigned long long evals = 0;
  g.evaluations = &evals;
  data.g = g;
  data.t0 = Clock::now();
  data.max_seconds = t.max_seconds;
  const unsigned d = static_cast<unsigned>(g.d);
  std::vector<double> lo(d, 0.0), hi(d, 1.0);
  double val = 0.0, err = 0.0;
  const size_t max_eval = static_cast<size_t>(t.max_evaluations);
  const int rc = m == CubatureMethod::h
                     ? hcubature(1, &integrand, &data, d, lo.data(), hi.data(), max_eval, 0.0, t.rel_half_width,
                                 ERROR_INDIVIDUAL, &val, &err)
                     : pcubature(1, &integrand, &data, d, lo.data(), hi.data(), max_eval, 0.0, t.rel_half_width,
                                 ERROR_INDIVIDUAL, &val, &err);
  PeerResult out;
  out.seconds = std::chrono::duration<double>(Clock::now() - data.t0).count();
  out.evaluations = evals;
  out.estimate = val;
  out.half_width = err;
  out.converged = rc == 0 && !data.timed_out && std::isfinite(err) && err <= t.rel_half_width * std::fabs(val);
  out.note = data.timed_out ? "time cap" : (out.converged ? "" : "eval cap");
  return out;
}

}  // namespace tally::peers
