#include "bench/peers/gsl_peers.hpp"

#include <gsl/gsl_monte.h>
#include <gsl/gsl_monte_miser.h>
#include <gsl/gsl_monte_plain.h>
#include <gsl/gsl_monte_vegas.h>
#include <gsl/gsl_rng.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <vector>

namespace tally::peers {

namespace {

using Clock = std::chrono::steady_clock;

double since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

// Next batch: aimed at the predicted total with 10% headroom, between `first` and
// the total so far (so the total at most doubles per round).
uint64_t next_batch(double total, double half_width, double target_hw, uint64_t first) {
  double want = static_cast<double>(first);
  if (std::isfinite(half_width) && target_hw > 0) {
    const double need = total * (half_width / target_hw) * (half_width / target_hw);
    want = 1.1 * need - total;
  }
  want = std::clamp(want, static_cast<double>(first), std::max(total, static_cast<double>(first)));
  return static_cast<uint64_t>(want);
}

}  // namespace

const char* gsl_method_name(GslMethod m) {
  switch (m) {
    case GslMethod::plain:
      return "gsl_plain";
    case GslMethod::miser:
      return "gsl_miser";
    default:
      return "gsl_vegas";
  }
}

PeerResult run_gsl(GslMethod m, GenzScalar g, const Target& t, unsigned long seed) {
  const auto t0 = Clock::now();
  unsigned long long evals = 0;
  g.evaluations = &evals;
  const size_t d = g.d;
  std::vector<double> lo(d, 0.0), hi(d, 1.0);
  gsl_monte_function F{&genz_scalar_gsl, d, &g};
  gsl_rng* rng = gsl_rng_alloc(gsl_rng_mt19937);
  gsl_rng_set(rng, seed);
  PeerResult out;
  auto over_caps = [&] { return evals >= t.max_evaluations || since(t0) >= t.max_seconds; };

  if (m == GslMethod::vegas) {
    gsl_monte_vegas_state* s = gsl_monte_vegas_alloc(d);
    double res = 0, err = 0;
    // Warm-up: adapt the grid on a small run, then discard its results (stage 1).
    gsl_monte_vegas_integrate(&F, lo.data(), hi.data(), d, t.first_batch / 4, rng, s, &res, &err);
    const unsigned long long warm = evals;
    uint64_t calls = t.first_batch / 4;
    bool first = true;
    while (true) {
      gsl_monte_vegas_params p;
      gsl_monte_vegas_params_get(s, &p);
      p.stage = first ? 1 : 3;  // then keep accumulating iterations on the refined grid
      gsl_monte_vegas_params_set(s, &p);
      gsl_monte_vegas_integrate(&F, lo.data(), hi.data(), d, calls, rng, s, &res, &err);
      first = false;
      out.estimate = res;
      out.half_width = t.z * err;
      const double chisq = gsl_monte_vegas_chisq(s);
      const bool consistent = std::isfinite(chisq) && chisq <= 1.5;
      if (out.half_width <= t.rel_half_width * std::fabs(res) && consistent) {
        out.converged = true;
        break;
      }
      if (over_caps()) {
        out.note = consistent ? "cap" : "cap (chi2/dof > 1.5)";
        break;
      }
      // Evaluations since the warm-up decide the next call's size; one call runs
      // p.iterations iterations of `calls` points each.
      const double accumulated = static_cast<double>(evals - warm);
      calls = std::max<uint64_t>(calls, next_batch(accumulated, out.half_width, t.rel_half_width * std::fabs(res),
                                                   t.first_batch) /
                                            std::max<unsigned>(1, p.iterations));
    }
    gsl_monte_vegas_free(s);
  } else {
    gsl_monte_plain_state* ps = m == GslMethod::plain ? gsl_monte_plain_alloc(d) : nullptr;
    gsl_monte_miser_state* ms = m == GslMethod::miser ? gsl_monte_miser_alloc(d) : nullptr;
    double sum_n = 0, sum_n_est = 0, sum_n2_var = 0;
    uint64_t batch = t.first_batch;
    while (true) {
      double res = 0, err = 0;
      if (ps) {
        gsl_monte_plain_integrate(&F, lo.data(), hi.data(), d, batch, rng, ps, &res, &err);
      } else {
        gsl_monte_miser_integrate(&F, lo.data(), hi.data(), d, batch, rng, ms, &res, &err);
      }
      const double n = static_cast<double>(batch);
      sum_n += n;
      sum_n_est += n * res;
      sum_n2_var += n * n * err * err;
      out.estimate = sum_n_est / sum_n;
      out.half_width = t.z * std::sqrt(sum_n2_var) / sum_n;
      if (out.half_width <= t.rel_half_width * std::fabs(out.estimate)) {
        out.converged = true;
        break;
      }
      if (over_caps()) {
        out.note = "cap";
        break;
      }
      batch = next_batch(sum_n, out.half_width, t.rel_half_width * std::fabs(out.estimate), t.first_batch);
    }
    if (ps) gsl_monte_plain_free(ps);
    if (ms) gsl_monte_miser_free(ms);
  }
  gsl_rng_free(rng);
  out.evaluations = evals;
  out.seconds = since(t0);
  return out;
}

}  // namespace tally::peers
