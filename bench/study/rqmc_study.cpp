// (e) Randomized QMC (scrambled Sobol, the product's "qmc" estimator, both scrambles) against
// plain Monte Carlo on smooth Genz integrands: RMSE of one estimate against its
// evaluations. Theory for smooth f: MC N^(-1/2), scrambled nets N^(-3/2) up to log factors.
#include <fmt/format.h>

#include <cmath>

#include "bench/study/study_support.hpp"

namespace tally::study {

void run_rqmc_study(const Options& o) {
  Csv csv(o.out / "rqmc.csv", {"family", "d", "method", "N", "replicates", "rel_rmse", "reported_rel_se",
                                "seconds_per_estimate", "exact"});
  const int reps = o.quick ? 8 : 32;
  const int max_log2 = o.quick ? 12 : 16;
  struct Case {
    GenzFamily f;
    double a;
  };
  const std::vector<Case> cases = {{GenzFamily::oscillatory, 1.0},
                                   {GenzFamily::gaussian, 1.5},
                                   {GenzFamily::product_peak, 2.0},
                                   {GenzFamily::corner_peak, 0.5}};
  for (size_t d : {size_t{2}, size_t{4}}) {
    for (const Case& c : cases) {
      GenzParams p;
      p.family = c.f;
      for (size_t i = 0; i < d; ++i) {
        p.a.push_back(c.a);
        p.u.push_back(0.3 + 0.4 * std::fmod(0.618033988749895 * static_cast<double>(i + 1), 1.0));
      }
      const double exact = genz_exact(p);
      const std::string fam(genz_family_name(c.f));
      for (int k = 6; k <= max_log2; ++k) {
        const uint64_t N = uint64_t{1} << k;
        // One job, `reps` independent scrambles of an N-point Sobol set.
        // Both scrambles of the product's qmc estimator: "owen" (nested uniform, the one
        // the N^-3/2 theory is about) and "affine" (the default, random linear + shift).
        for (const char* scramble : {"owen", "affine"}) {
          const JobRun r = run_spec(
              genz_spec(p, {{"type", "qmc"}, {"points", N}, {"scramble", scramble}},
                        {{"max_samples", reps}, {"min_samples", 2}}, 11),
              o.threads);
          const Tally& t = r.runner->state().channels[0];
          const double mse = (t.m2 + static_cast<double>(t.n) * (t.mean - exact) * (t.mean - exact)) /
                             static_cast<double>(t.n);
          csv.row({fam, d, std::string(scramble) == "owen" ? "rqmc" : "rqmc_affine", N, reps,
                   std::sqrt(mse) / std::fabs(exact), std::sqrt(t.variance()) / std::fabs(exact),
                   r.compute_seconds() / reps, exact});
        }
        const SeedStats s = over_seeds(
            [&](uint64_t seed) { return genz_spec(p, {{"type", "uniform"}}, {{"max_samples", N}}, seed); }, exact,
            reps, o.threads);
        csv.row({fam, d, "monte_carlo", N, reps, s.rmse / std::fabs(exact), std::sqrt(s.reported_var) / std::fabs(exact),
                 s.seconds, exact});
      }
      log(fmt::format("rqmc {} d={} done", fam, d));
    }
  }
}

}  // namespace tally::study
