// (b) Variance falls as 1/N: the spread of the plain Monte Carlo estimate across
// independent seeds against N, beside the engine's own reported std_error^2.
#include <fmt/format.h>

#include "bench/study/study_support.hpp"

namespace tally::study {

void run_variance_study(const Options& o) {
  Csv csv(o.out / "variance.csv",
          {"integrand", "N", "seeds", "variance_across_seeds", "mean_reported_variance", "rmse", "exact"});
  const int seeds = o.quick ? 8 : 64;
  const int max_log2 = o.quick ? 12 : 18;
  struct Case {
    std::string name;
    GenzParams p;
  };
  std::vector<Case> cases;
  cases.push_back({"gaussian_2d", {GenzFamily::gaussian, {1.5, 2.5}, {0.35, 0.6}}});
  cases.push_back({"oscillatory_4d", {GenzFamily::oscillatory, {1.0, 1.5, 0.5, 2.0}, {0.2, 0.5, 0.5, 0.5}}});
  for (const Case& c : cases) {
    const double exact = genz_exact(c.p);
    for (int k = 4; k <= max_log2; ++k) {
      const uint64_t N = uint64_t{1} << k;
      const SeedStats s = over_seeds(
          [&](uint64_t seed) { return genz_spec(c.p, {{"type", "uniform"}}, {{"max_samples", N}}, seed); }, exact,
          seeds, o.threads);
      csv.row({c.name, N, seeds, s.variance, s.reported_var, s.rmse, exact});
    }
    log("variance " + c.name + " done");
  }
}

}  // namespace tally::study
