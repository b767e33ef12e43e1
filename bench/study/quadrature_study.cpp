// (a) The lecture's quadrature argument: tensor-product trapezoid against plain Monte
// Carlo on smooth Genz integrands in d = 1..8. Trapezoid error falls as N^(-2/d) in
// N = n^d evaluations, Monte Carlo's as N^(-1/2) whatever d: MC wins once d > 4.
#include <fmt/format.h>

#include <cmath>
#include <numbers>

#include "bench/study/study_support.hpp"

namespace tally::study {

namespace {

// Smooth instances with the same per-axis difficulty in every d (so only d changes).
GenzParams smooth_instance(GenzFamily f, size_t d) {
  GenzParams p;
  p.family = f;
  for (size_t i = 0; i < d; ++i) {
    const double phi = std::fmod(0.618033988749895 * static_cast<double>(i + 1), 1.0);
    p.u.push_back(0.3 + 0.4 * phi);
    p.a.push_back(f == GenzFamily::gaussian ? 1.5 : 1.0);
  }
  if (f == GenzFamily::oscillatory) {
    // Put the phase 2 pi u_1 + sum(a)/2 at 0 mod 2 pi: |I| is then as large as it gets,
    // so relative errors mean the same in every d.
    double sum_a = 0.0;
    for (double a : p.a) sum_a += a;
    p.u[0] = std::fmod(10.0 - sum_a / (4.0 * std::numbers::pi), 1.0);
  }
  return p;
}

// n = 3 .. n_max, roughly geometric (ratio ~1.4), with n_max^d <= max_points.
std::vector<uint32_t> trapezoid_sizes(size_t d, double max_points) {
  const double n_max = std::floor(std::pow(max_points, 1.0 / static_cast<double>(d)) + 1e-9);
  std::vector<uint32_t> out;
  double n = 3;
  while (n <= n_max) {
    const auto k = static_cast<uint32_t>(std::lround(n));
    if (out.empty() || k != out.back()) out.push_back(k);
    n *= 1.4;
  }
  if (out.back() != static_cast<uint32_t>(n_max)) out.push_back(static_cast<uint32_t>(n_max));
  return out;
}

}  // namespace

void run_quadrature_study(const Options& o) {
  Csv csv(o.out / "quadrature.csv", {"family", "d", "method", "n_per_dim", "evaluations", "seconds", "estimate",
                                      "exact", "rel_error", "reported_rel_error", "seeds"});
  const std::vector<size_t> dims = {1, 2, 3, 4, 5, 6, 8};
  const int seeds = o.quick ? 4 : 32;
  const int mc_max_log2 = o.quick ? 14 : 19;
  for (GenzFamily f : {GenzFamily::gaussian, GenzFamily::oscillatory}) {
    const std::string fam(genz_family_name(f));
    for (size_t d : dims) {
      const GenzParams p = smooth_instance(f, d);
      const double exact = genz_exact(p);
      const double max_points = o.quick ? 1e5 : (d == 1 ? 32769.0 : 16777216.0);
      for (uint32_t n : trapezoid_sizes(d, max_points)) {
        const JobRun r = run_spec(genz_spec(p, {{"type", "quadrature"}, {"rule", "trapezoid"}, {"points_per_dim", n}},
                                            {{"max_samples", 1}}, 1),
                                  o.threads);
        const double est = r.runner->estimate(0).mean;
        csv.row({fam, d, "trapezoid", n, r.evaluations(), r.compute_seconds(), est, exact,
                 std::fabs(est - exact) / std::fabs(exact), r.runner->error().rel_error, 1});
      }
      for (int k = 8; k <= mc_max_log2; ++k) {
        const uint64_t N = uint64_t{1} << k;
        const SeedStats s = over_seeds(
            [&](uint64_t seed) { return genz_spec(p, {{"type", "uniform"}}, {{"max_samples", N}}, seed); }, exact,
            seeds, o.threads);
        csv.row({fam, d, "monte_carlo", nullptr, s.evaluations, s.seconds, s.mean, exact, s.rmse / std::fabs(exact),
                 std::sqrt(s.reported_var) / std::fabs(exact), seeds});
      }
      log(fmt::format("quadrature {} d={} done", fam, d));
    }
  }
}

}  // namespace tally::study
