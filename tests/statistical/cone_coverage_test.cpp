// How often the cone rule's bound (`"estimator": {"type": "qmc", "error": "cone"}`,
// common/integrate/cone_rule.hpp) holds: the fraction of runs with |mean - I| <= bound on
// random Genz instances (genz_random_instance) and scrambles. The bound is deterministic
// for integrands in the cone, not a 95% interval: no coverage is promised, and what it is
// is measured. The discontinuous family is outside any cone (its Walsh coefficients do not
// decay); its figure is printed, not asserted.
// TALLY_CONE_RUNS overrides the runs per case (docs/jobs.md quotes a larger run).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>

#include "common/integrate/genz.hpp"
#include "common/integrate/integration_counters.hpp"
#include "integrate/run_support.hpp"

namespace tally {
namespace {

using nlohmann::json;

struct Cover {
  int covered = 0, met = 0, runs = 0;
  double evaluations = 0;  // summed
  double fraction() const { return static_cast<double>(covered) / runs; }
};

// `runs` instances (instance seed i) of family f in d dimensions, each with its own
// scramble (job seed), at relative target `rel`.
Cover cone_coverage(GenzFamily f, size_t d, double rel, int runs, const json& estimator = {{"type", "qmc"}, {"error", "cone"}}) {
  Cover c;
  for (int i = 0; i < runs; ++i) {
    const GenzParams p = genz_random_instance(f, d, static_cast<uint64_t>(9000 + i));
    const double exact = genz_exact(p);
    const json spec = {
        {"kind", "integrate"},
        {"seed", 300000 + i},
        {"integrand", {{"builtin", "genz"}, {"family", genz_family_name(f)}, {"a", p.a}, {"u", p.u}}},
        {"estimator", estimator},
        {"stop", {{"rel_error", rel}, {"max_samples", estimator["type"] == "lattice" ? 1 << 20 : 1 << 22}}}};
    const auto r = testing::run_spec(spec, 1);
    const ErrorSummary e = r->error();
    ++c.runs;
    c.covered += std::fabs(e.mean - exact) <= e.abs_error ? 1 : 0;
    c.met += r->stop_reason() == StopReason::error_target ? 1 : 0;
    c.evaluations += static_cast<double>(r->state().counters[IntegrationCounter::evaluations]);
  }
  std::printf("%s cone coverage %.4f (%d/%d), target met %d, mean points %.0f: %s d=%zu rel=%g\n",
              estimator["type"].get<std::string>().c_str(), c.fraction(), c.covered, c.runs, c.met,
              c.evaluations / c.runs,
              std::string(genz_family_name(f)).c_str(), d, rel);
  return c;
}

int runs_per_case(int fallback) {
  const char* v = std::getenv("TALLY_CONE_RUNS");
  return v != nullptr && std::atoi(v) > 0 ? std::atoi(v) : fallback;
}

// d = 8, 3 digits (relative 1e-3): 200 runs a family. Measured 0.96-1.00 on the smooth
// families (docs/jobs.md); the test guards 0.93: at a true 0.965 (the lowest measured
// families' mean) 15 or more misses of 200 have probability 0.005. Seeds are fixed, so the
// test is deterministic either way.
TEST(ConeCoverage, SmoothFamiliesInEightDimensions) {
  const int runs = runs_per_case(200);
  for (GenzFamily f : {GenzFamily::oscillatory, GenzFamily::product_peak, GenzFamily::corner_peak,
                       GenzFamily::gaussian, GenzFamily::continuous}) {
    const Cover c = cone_coverage(f, 8, 1e-3, runs);
    EXPECT_GE(c.fraction(), 0.93) << genz_family_name(f);
  }
  cone_coverage(GenzFamily::discontinuous, 8, 1e-3, runs);
}

// The lattice form (`"type": "lattice", "error": "cone"`, baker's transform), the same
// instances, shifts seeded by the job seed. Measured 0.98-1.00 on the smooth families
// (docs/jobs.md); guarded as above.
TEST(ConeCoverage, LatticeSmoothFamiliesInEightDimensions) {
  const int runs = runs_per_case(200);
  const json lattice = {{"type", "lattice"}, {"error", "cone"}};
  for (GenzFamily f : {GenzFamily::oscillatory, GenzFamily::product_peak, GenzFamily::corner_peak,
                       GenzFamily::gaussian, GenzFamily::continuous}) {
    const Cover c = cone_coverage(f, 8, 1e-3, runs, lattice);
    EXPECT_GE(c.fraction(), 0.93) << genz_family_name(f);
  }
  // Printed only, and on a quarter of the runs: most run to the lattice's 2^20 points.
  cone_coverage(GenzFamily::discontinuous, 8, 1e-3, std::max(1, runs / 4), lattice);
}

}  // namespace
}  // namespace tally
