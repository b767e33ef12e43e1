// The VEGAS estimator (common/integrate/vegas.hpp): closed-form Genz checks in 1-8
// dimensions, the grid's sampling against its own density, bit-identity across
// thread counts and resumes in the middle of the adaptation, and the chi^2 warning.
#include <gtest/gtest.h>

#include <algorithm>
#include <boost/math/distributions/chi_squared.hpp>
#include <cmath>
#include <fstream>
#include <iterator>
#include <string>
#include <utility>

#include "common/engine/checkpoint.hpp"
#include "common/spec/spec_reader.hpp"
#include "common/integrate/genz.hpp"
#include "common/integrate/vector_integrand.hpp"
#include "common/integrate/vegas.hpp"
#include "integrate/run_support.hpp"

namespace tally {
namespace {

using nlohmann::json;

json vegas_spec(const GenzParams& p, uint64_t seed, uint64_t max_samples, json est = {{"type", "vegas"}}) {
  return {{"kind", "integrate"},
          {"seed", seed},
          {"integrand", {{"builtin", "genz"}, {"family", genz_family_name(p.family)}, {"a", p.a}, {"u", p.u}}},
          {"estimator", est},
          {"stop", {{"max_samples", max_samples}}}};
}

GenzParams instance(GenzFamily f, size_t d) {
  GenzParams p;
  p.family = f;
  for (size_t i = 0; i < d; ++i) {
    p.u.push_back(0.25 + 0.5 * std::fmod(0.618 * static_cast<double>(i + 1), 1.0));
    // Cuba's difficulty h spread evenly over the axes.
    const double h[] = {6.0, 18.0, 2.2, 15.2, 16.1, 16.4};
    p.a.push_back(h[static_cast<int>(f)] / static_cast<double>(d));
  }
  return p;
}

// |estimate - exact| <= 4 reported standard errors: a correct estimator fails one
// check with probability 6e-5 (normal limit); 48 checks, seeds fixed.
TEST(Vegas, GenzClosedFormsInOneToEightDimensions) {
  for (size_t d = 1; d <= 8; ++d) {
    for (GenzFamily f : {GenzFamily::oscillatory, GenzFamily::product_peak, GenzFamily::corner_peak,
                         GenzFamily::gaussian, GenzFamily::continuous, GenzFamily::discontinuous}) {
      const GenzParams p = instance(f, d);
      const double exact = genz_exact(p);
      const auto r = testing::run_spec(vegas_spec(p, 7 + d, 4096 * 31), 2);
      const Estimate e = r->headline();
      ASSERT_GT(e.n, 60000u);  // 4 post-warm-up passes of 4096 * 2^k
      EXPECT_LE(std::fabs(e.mean - exact), 4.0 * e.std_error)
          << genz_family_name(f) << " d=" << d << " mean " << e.mean << " exact " << exact << " se " << e.std_error;
      EXPECT_GT(e.std_error, 0.0);
    }
  }
}

// The adapted grid concentrates where a product peak is, and its error beats uniform
// sampling's at the same number of samples.
TEST(Vegas, AdaptationReducesTheVarianceOnAPeak) {
  const GenzParams p{GenzFamily::product_peak, {20.0, 20.0}, {0.3, 0.7}};
  const auto vegas = testing::run_spec(vegas_spec(p, 3, 4096 * 31), 1);
  const auto uniform = testing::run_spec(vegas_spec(p, 3, 4096 * 31, {{"type", "uniform"}}), 1);
  EXPECT_LT(vegas->headline().std_error * 3.0, uniform->estimate(0).std_error);
  const auto rep = vegas_report(vegas->state());
  ASSERT_TRUE(rep);
  EXPECT_EQ(rep->iterations.size(), 5u);
  EXPECT_EQ(rep->used, 2u);  // 3 warm-up passes by default
  // The density at the peak exceeds the uniform density 1 by far.
  const double at_peak[2] = {0.3, 0.7};
  EXPECT_GT(vegas_grid_density(rep->grid, at_peak), 5.0);
}

// Points drawn from an adapted grid (the kernel's own mapping) histogrammed into
// 12 x 12 cells that do not align with the bins, against the exact cell
// probabilities of the separable piecewise-uniform density: Pearson chi^2 with 143
// degrees of freedom, rejected at p < 1e-6 (false-failure rate 1e-6). The pdf the
// kernel divides by must equal the grid's density at the point.
TEST(Vegas, GridSamplingMatchesItsDensity) {
  const GenzParams p{GenzFamily::corner_peak, {3.0, 1.0}, {0.5, 0.5}};
  const auto r = testing::run_spec(vegas_spec(p, 5, 4096 * 7), 1);
  const auto rep = vegas_report(r->state());
  ASSERT_TRUE(rep);
  const auto& g = rep->grid;
  ASSERT_EQ(g.size(), 2u);
  auto cdf = [](const std::vector<double>& e, double x) {
    const size_t nb = e.size() - 1;
    for (size_t j = 0; j < nb; ++j) {
      if (x <= e[j + 1]) return (static_cast<double>(j) + (e[j + 1] > e[j] ? (x - e[j]) / (e[j + 1] - e[j]) : 1.0)) / nb;
    }
    return 1.0;
  };
  constexpr size_t kCells = 12, kN = 400000;
  std::vector<std::vector<double>> pts;
  std::vector<double> pdf;
  vegas_draw(g, 99, 0, kN, pts, pdf);
  std::vector<double> counts(kCells * kCells, 0.0);
  for (size_t i = 0; i < kN; ++i) {
    const double x[2] = {pts[0][i], pts[1][i]};
    ASSERT_DOUBLE_EQ(pdf[i], vegas_grid_density(g, x));
    const size_t cx = std::min(kCells - 1, static_cast<size_t>(x[0] * kCells));
    const size_t cy = std::min(kCells - 1, static_cast<size_t>(x[1] * kCells));
    counts[cy * kCells + cx] += 1.0;
  }
  double chi2 = 0.0;
  for (size_t cy = 0; cy < kCells; ++cy) {
    const double py = cdf(g[1], (cy + 1.0) / kCells) - cdf(g[1], static_cast<double>(cy) / kCells);
    for (size_t cx = 0; cx < kCells; ++cx) {
      const double px = cdf(g[0], (cx + 1.0) / kCells) - cdf(g[0], static_cast<double>(cx) / kCells);
      const double expected = kN * px * py;
      ASSERT_GT(expected, 5.0);
      const double o = counts[cy * kCells + cx];
      chi2 += (o - expected) * (o - expected) / expected;
    }
  }
  const double limit = boost::math::quantile(boost::math::chi_squared(kCells * kCells - 1), 1.0 - 1e-6);
  EXPECT_LT(chi2, limit);
  // The grid is not uniform: the density varies by more than 2x across the square.
  const double lo[2] = {0.95, 0.95}, hi[2] = {0.02, 0.02};
  EXPECT_GT(vegas_grid_density(g, hi), 2.0 * vegas_grid_density(g, lo));
}

using testing::expect_same_state;

const json kDeterminismSpec = vegas_spec(GenzParams{GenzFamily::discontinuous, {2.0, 3.0, 1.5}, {0.6, 0.4, 0.5}},
                                         17, 4096 * 63);

TEST(Vegas, OneAndTwoThreadsGiveIdenticalBits) {
  const auto one = testing::run_spec(kDeterminismSpec, 1);
  const auto two = testing::run_spec(kDeterminismSpec, 2);
  EXPECT_EQ(one->state().passes, 6u);
  expect_same_state(one->state(), two->state());
}

// Checkpoints taken in the warm-up (passes 1, 2) and after it (4), resumed from
// their bytes, end bit-identical to the uninterrupted run.
TEST(Vegas, ResumeMidAdaptationIsBitIdentical) {
  const auto ref = testing::run_spec(kDeterminismSpec, 2);
  for (uint64_t stop_after : {1, 2, 4}) {
    const testing::Interrupted first = testing::run_until_pass(kDeterminismSpec, stop_after);
    ASSERT_FALSE(first.checkpoint.empty());
    JobState restored = decode_checkpoint(first.checkpoint);
    EXPECT_EQ(restored.kernel_state, first.run->state().kernel_state);
    expect_same_state(ref->state(), testing::resume_spec(kDeterminismSpec, std::move(restored))->state());
  }
}

// Iterations whose estimates disagree far beyond their errors: a warning, and the
// error bar scaled by sqrt(chi^2/dof) (so an error target is not silently "met").
TEST(Vegas, DisagreeingIterationsWarnAndWidenTheError) {
  const GenzParams p{GenzFamily::gaussian, {1.0, 1.0}, {0.5, 0.5}};
  auto job = compile_job(vegas_spec(p, 1, 1000, {{"type", "vegas"}, {"bins", 4}, {"warmup_passes", 0}}), JobLimits{});
  const Kernel& k = *job->kernel();
  JobState st;
  st.channels.assign(k.channel_count(), Tally{});
  // Three passes: means 1.0, 1.0, 1.5 with standard errors ~0.01.
  for (double mean : {1.0, 1.0, 1.5}) {
    BlockResult r;
    r.aux.assign(2 * 4, 1.0);  // 2 axes x 4 bins of (f/p)^2 sums
    r.aux.push_back(10000.0);  // n
    r.aux.push_back(mean);
    r.aux.push_back(9999.0);  // m2: variance 1, se 0.01
    std::vector<BlockResult> results;
    results.push_back(std::move(r));
    k.fold_pass(k.pass_input(st), results, st);
    st.passes += 1;
  }
  st.channels[0] = Tally{30000, 7.0 / 6.0, 29999.0};
  const auto rep = vegas_report(st);
  ASSERT_TRUE(rep);
  EXPECT_EQ(rep->used, 3u);
  // chi^2 = (1/6)^2/1e-4 * 2 + (1/3)^2/1e-4 = 1666.7 on 2 dof.
  EXPECT_NEAR(rep->chi2, 2.0 * (1.0 / 36.0) / 1e-4 + (1.0 / 9.0) / 1e-4, 1e-6);
  EXPECT_TRUE(rep->inconsistent);
  EXPECT_NEAR(rep->error_scale, std::sqrt(rep->chi2 / 2.0), 1e-9);
  const auto w = k.warnings(st);
  ASSERT_EQ(w.size(), 1u);
  EXPECT_NE(w[0].find("VEGAS iterations disagree"), std::string::npos);
  const ErrorSummary e = k.error_summary(st, 0.95);
  EXPECT_NEAR(e.sigma, 1.0 * rep->error_scale, 1e-6);
}

TEST(Vegas, RejectsNonBoxDomainsAndBadOptions) {
  const json disk = {{"kind", "integrate"},
                     {"integrand", {{"expression", "x*y"}}},
                     {"domain", {{"type", "disk"}}},
                     {"estimator", {{"type", "vegas"}}},
                     {"stop", {{"max_samples", 1000}}}};
  try {
    compile_job(disk, JobLimits{});
    FAIL() << "accepted a disk";
  } catch (const SpecError& e) {
    EXPECT_EQ(e.pointer(), "/estimator/type");
  }
  json bad = disk;
  bad["domain"] = {{"type", "box"}, {"lower", {0, 0}}, {"upper", {1, 1}}};
  bad["estimator"]["bins"] = 1;
  try {
    compile_job(bad, JobLimits{});
    FAIL() << "accepted 1 bin";
  } catch (const SpecError& e) {
    EXPECT_EQ(e.pointer(), "/estimator/bins");
  }
}

}  // namespace
}  // namespace tally

namespace tally {
namespace {

json vector_spec(json integrand, json est, uint64_t max_samples = 4096 * 31) {
  return {{"kind", "integrate"},
          {"seed", 21},
          {"integrand", std::move(integrand)},
          {"domain", {{"type", "box"}, {"lower", {0.0, 0.0, 0.0}}, {"upper", {1.0, 2.0, 1.0}}}},
          {"estimator", std::move(est)},
          {"stop", {{"max_samples", max_samples}}}};
}

const char* kE1 = "exp(-3*((x0-0.3)^2+(x1-0.8)^2+(x2-0.5)^2))";
const char* kE2 = "x0*x1 + sin(x2)";
const char* kE3 = "1/(0.1+x0+x1*x2)";

// Points do not depend on the integrand with a frozen grid (uniform; vegas with
// alpha = 0): every component of a vector run equals its scalar run bit for bit.
TEST(VectorIntegrand, EachComponentEqualsItsScalarRunWhenPointsAreShared) {
  for (const json& est : {json{{"type", "uniform"}}, json{{"type", "vegas"}, {"alpha", 0.0}}}) {
    const auto vec = testing::run_spec(vector_spec({{"expressions", {kE1, kE2, kE3}}}, est), 2);
    ASSERT_EQ(vec->state().channels.size(), 3u + 3u);  // 3 components + 3 pairs
    const char* scalars[] = {kE1, kE2, kE3};
    for (size_t c = 0; c < 3; ++c) {
      json e = est;
      if (e["type"] == "uniform") e = {{"type", "vegas"}, {"alpha", 0.0}, {"bins", 2}, {"warmup_passes", 0}};
      const auto one = testing::run_spec(vector_spec({{"expression", scalars[c]}}, e), 1);
      EXPECT_EQ(vec->state().channels[c], one->state().channels[0]) << c << " " << est.dump();
    }
  }
}

// Adaptive VEGAS steers by the components' normalized (f/p)^2: the same function
// given twice steers exactly as it does alone, so both components equal the scalar
// VEGAS run bit for bit (grid and all).
TEST(VectorIntegrand, TwiceTheSameFunctionSteersLikeTheScalarRun) {
  const json est = {{"type", "vegas"}};
  const auto vec = testing::run_spec(vector_spec({{"expressions", {kE1, kE1}}}, est), 2);
  const auto one = testing::run_spec(vector_spec({{"expression", kE1}}, est), 1);
  EXPECT_EQ(vec->state().channels[0], one->state().channels[0]);
  EXPECT_EQ(vec->state().channels[1], one->state().channels[0]);
  EXPECT_EQ(vegas_report(vec->state())->grid, vegas_report(one->state())->grid);
}

// The covariance of the component means: f and 2f + 1 have cov = 2 var(f)/n and
// correlation 1; the stop rule looks at the worst component.
TEST(VectorIntegrand, CovarianceAndWorstComponentStopRule) {
  // Uniform points (constant Jacobian 2 = the box's measure), so sample 2 = 2 * sample 1 + 2.
  const auto r = testing::run_spec(vector_spec({{"expressions", {kE2, "2*(x0*x1 + sin(x2)) + 1"}}},
                                               {{"type", "uniform"}}),
                                   1);
  const std::vector<double> cov = component_mean_covariance(r->state(), 2);
  EXPECT_NEAR(cov[1], 2.0 * cov[0], 1e-9 * std::fabs(cov[0]) + 1e-15);
  EXPECT_NEAR(cov[3], 4.0 * cov[0], 1e-9 * std::fabs(cov[0]) + 1e-15);
  EXPECT_EQ(cov[1], cov[2]);
  const ErrorSummary e = r->error();
  EXPECT_DOUBLE_EQ(e.abs_error, r->kernel().error_summary(r->state(), 0.95).abs_error);
  // The second component's half-width (twice the first's) decides.
  EXPECT_NEAR(e.abs_error, 1.959963984540054 * std::sqrt(cov[3]), 1e-3 * e.abs_error);
  const json res = kind_result_json(*r.job, *r.runner);
  ASSERT_EQ(res.at("components").size(), 2u);
  EXPECT_NEAR(res["components"][1]["mean"].get<double>(), 2.0 * res["components"][0]["mean"].get<double>() + 2.0, 1e-9);
}

TEST(VectorIntegrand, BuiltInGenzFamiliesShareThePoints) {
  const json spec = {{"kind", "integrate"},
                     {"seed", 4},
                     {"integrand", {{"builtin", "genz"}, {"families", {"gaussian", "product_peak"}},
                                    {"a", {2.0, 3.0}}, {"u", {0.4, 0.6}}}},
                     {"estimator", {{"type", "vegas"}}},
                     {"stop", {{"max_samples", 4096 * 31}}}};
  const auto r = testing::run_spec(spec, 2);
  for (size_t c = 0; c < 2; ++c) {
    const GenzParams p{c == 0 ? GenzFamily::gaussian : GenzFamily::product_peak, {2.0, 3.0}, {0.4, 0.6}};
    const Estimate e = r->estimate(c);
    EXPECT_LE(std::fabs(e.mean - genz_exact(p)), 4.0 * e.std_error) << c;
  }
}

TEST(VectorIntegrand, BadSpecsNameTheField) {
  auto pointer_of = [](json spec) {
    try {
      compile_job(spec, JobLimits{});
    } catch (const SpecError& e) {
      return e.pointer();
    }
    return std::string("accepted");
  };
  EXPECT_EQ(pointer_of(vector_spec({{"expressions", {kE1, "x0 +"}}}, {{"type", "vegas"}})), "/integrand/expressions/1");
  EXPECT_EQ(pointer_of(vector_spec({{"expressions", json::array()}}, {{"type", "vegas"}})), "/integrand/expressions");
  EXPECT_EQ(pointer_of(vector_spec({{"expressions", {kE1, kE2}}}, {{"type", "stratified"}})), "/estimator/type");
}

}  // namespace
}  // namespace tally

// ---- VEGAS+ (adaptive stratification, "stratify": true) ----
namespace tally {
namespace {

json plus_spec(const GenzParams& p, uint64_t seed, uint64_t max_samples) {
  return vegas_spec(p, seed, max_samples, {{"type", "vegas"}, {"stratify", true}});
}

// Closed forms in d = 1..8 for the six families within 4 reported standard errors
// (48 checks at a 6e-5 false-failure rate each, seeds fixed).
TEST(VegasPlus, GenzClosedFormsInOneToEightDimensions) {
  for (size_t d = 1; d <= 8; ++d) {
    for (GenzFamily f : {GenzFamily::oscillatory, GenzFamily::product_peak, GenzFamily::corner_peak,
                         GenzFamily::gaussian, GenzFamily::continuous, GenzFamily::discontinuous}) {
      const GenzParams p = instance(f, d);
      const double exact = genz_exact(p);
      const auto r = testing::run_spec(plus_spec(p, 7 + d, 4096 * 31), 2);
      const Estimate e = r->headline();
      EXPECT_LE(std::fabs(e.mean - exact), 4.0 * e.std_error)
          << genz_family_name(f) << " d=" << d << " mean " << e.mean << " exact " << exact << " se " << e.std_error;
      EXPECT_GT(e.std_error, 0.0);
      const auto rep = vegas_report(r->state());
      ASSERT_TRUE(rep);
      EXPECT_EQ(rep->strata_per_axis, vegas_strata_per_axis(d));
      EXPECT_EQ(rep->hypercubes, static_cast<uint64_t>(std::pow(rep->strata_per_axis, d) + 0.5));
    }
  }
}

// Stratification pays where the grid alone cannot follow the integrand: on the
// discontinuous family (jumps not aligned with the bins) and a product peak the
// reported error at equal samples is smaller than plain VEGAS's, and the allocation
// moved samples (hypercubes no longer get equal shares).
TEST(VegasPlus, StratificationReducesTheErrorAtEqualSamples) {
  for (const GenzParams& p : {GenzParams{GenzFamily::discontinuous, {3.0, 5.0}, {0.6, 0.45}},
                              GenzParams{GenzFamily::product_peak, {20.0, 20.0}, {0.3, 0.7}}}) {
    const auto plain = testing::run_spec(vegas_spec(p, 3, 4096 * 31), 1);
    const auto plus = testing::run_spec(plus_spec(p, 3, 4096 * 31), 1);
    EXPECT_LT(plus->headline().std_error * 1.5, plain->headline().std_error) << genz_family_name(p.family);
    std::printf("%s: vegas se %.3g, vegas+ se %.3g\n", genz_family_name(p.family).data(),
                plain->headline().std_error, plus->headline().std_error);
    const auto rep = vegas_report(plus->state());
    ASSERT_TRUE(rep);
    EXPECT_EQ(rep->hypercubes, 32u * 32u);
    const auto [lo, hi] = std::minmax_element(rep->next_allocation.begin(), rep->next_allocation.end());
    EXPECT_GE(*lo, 2u);
    EXPECT_GT(*hi, *lo + 1);
    uint64_t total = 0;
    for (uint64_t n : rep->next_allocation) total += n;
    EXPECT_EQ(total, kVegasRound);
  }
}

// Points drawn with stratification (the kernel's mapping, a real adapted grid and
// allocation), histogrammed into 12 x 12 cells against the exact cell probabilities of
// the density a sample at a random position of a round has: grid density * H n_h / R,
// piecewise constant on rectangles cut by the bin edges and the strata's images.
// Pearson chi^2, 143 dof, rejected at p < 1e-6 (stratified draws vary less than
// multinomial ones, so the test is conservative). The pdf of each point must equal
// that density computed independently (inverse grid map -> hypercube).
TEST(VegasPlus, StratifiedSamplingMatchesItsDensity) {
  const GenzParams p{GenzFamily::product_peak, {12.0, 6.0}, {0.3, 0.6}};
  const auto r = testing::run_spec(plus_spec(p, 5, 4096 * 7), 1);
  const auto rep = vegas_report(r->state());
  ASSERT_TRUE(rep);
  const auto& g = rep->grid;
  const uint32_t ns = rep->strata_per_axis;
  const std::vector<uint64_t>& alloc = rep->next_allocation;
  ASSERT_EQ(alloc.size(), static_cast<size_t>(ns) * ns);
  const double H = static_cast<double>(alloc.size()), R = static_cast<double>(kVegasRound);
  auto y_of = [&](size_t k, double x) {  // inverse grid map, axis k
    const auto& e = g[k];
    const size_t nb = e.size() - 1;
    size_t j = static_cast<size_t>(std::upper_bound(e.begin(), e.end(), x) - e.begin());
    j = std::clamp<size_t>(j, 1, nb) - 1;
    return (static_cast<double>(j) + (x - e[j]) / (e[j + 1] - e[j])) / static_cast<double>(nb);
  };
  auto x_of = [&](size_t k, double y) {  // grid map, axis k
    const auto& e = g[k];
    const size_t nb = e.size() - 1;
    const double t = y * static_cast<double>(nb);
    const size_t j = std::min(nb - 1, static_cast<size_t>(t));
    return e[j] + (t - static_cast<double>(j)) * (e[j + 1] - e[j]);
  };
  constexpr size_t kCells = 12;
  // Per axis: elementary intervals between all breakpoints (bin edges, strata images,
  // cell edges), each with its length, grid density factor, stratum and cell.
  struct Piece {
    double len, dens;
    size_t stratum, cell;
  };
  std::vector<std::vector<Piece>> pieces(2);
  for (size_t k = 0; k < 2; ++k) {
    std::vector<double> br(g[k].begin(), g[k].end());
    for (uint32_t s = 0; s <= ns; ++s) br.push_back(x_of(k, static_cast<double>(s) / ns));
    for (size_t c = 0; c <= kCells; ++c) br.push_back(static_cast<double>(c) / kCells);
    std::sort(br.begin(), br.end());
    for (size_t i = 0; i + 1 < br.size(); ++i) {
      const double a = br[i], b = br[i + 1];
      if (!(b > a)) continue;
      const double mid = 0.5 * (a + b);
      const size_t nb = g[k].size() - 1;
      size_t j = static_cast<size_t>(std::upper_bound(g[k].begin(), g[k].end(), mid) - g[k].begin());
      j = std::clamp<size_t>(j, 1, nb) - 1;
      const double dens = 1.0 / (static_cast<double>(nb) * (g[k][j + 1] - g[k][j]));
      const size_t s = std::min<size_t>(ns - 1, static_cast<size_t>(y_of(k, mid) * ns));
      pieces[k].push_back({b - a, dens, s, std::min(kCells - 1, static_cast<size_t>(mid * kCells))});
    }
  }
  std::vector<double> prob(kCells * kCells, 0.0);
  for (const Piece& a : pieces[0]) {
    for (const Piece& b : pieces[1]) {
      const size_t h = a.stratum + ns * b.stratum;  // axis 0 is the lowest digit
      prob[b.cell * kCells + a.cell] += a.len * b.len * a.dens * b.dens * H * static_cast<double>(alloc[h]) / R;
    }
  }
  double total = 0.0;
  for (double q : prob) total += q;
  ASSERT_NEAR(total, 1.0, 1e-9);
  constexpr size_t kN = kVegasRound * 100;
  std::vector<std::vector<double>> pts;
  std::vector<double> pdf;
  vegas_plus_draw(g, ns, alloc, 99, 4096, 4096, kN, pts, pdf);
  std::vector<double> counts(kCells * kCells, 0.0);
  for (size_t i = 0; i < kN; ++i) {
    const double x[2] = {pts[0][i], pts[1][i]};
    const size_t h = std::min<size_t>(ns - 1, static_cast<size_t>(y_of(0, x[0]) * ns)) +
                     ns * std::min<size_t>(ns - 1, static_cast<size_t>(y_of(1, x[1]) * ns));
    ASSERT_NEAR(pdf[i], vegas_grid_density(g, x) * H * static_cast<double>(alloc[h]) / R, 1e-9 * pdf[i]) << i;
    counts[std::min(kCells - 1, static_cast<size_t>(x[1] * kCells)) * kCells +
           std::min(kCells - 1, static_cast<size_t>(x[0] * kCells))] += 1.0;
  }
  double chi2 = 0.0;
  for (size_t c = 0; c < kCells * kCells; ++c) {
    const double expected = static_cast<double>(kN) * prob[c];
    ASSERT_GT(expected, 5.0);
    chi2 += (counts[c] - expected) * (counts[c] - expected) / expected;
  }
  EXPECT_LT(chi2, boost::math::quantile(boost::math::chi_squared(kCells * kCells - 1), 1.0 - 1e-6));
  // A wrong density is caught: the grid's density alone (ignoring the allocation).
  double chi2_wrong = 0.0;
  {
    std::vector<double> pw(kCells * kCells, 0.0);
    for (const Piece& a : pieces[0]) {
      for (const Piece& b : pieces[1]) pw[b.cell * kCells + a.cell] += a.len * b.len * a.dens * b.dens;
    }
    for (size_t c = 0; c < kCells * kCells; ++c) {
      const double expected = static_cast<double>(kN) * pw[c];
      chi2_wrong += (counts[c] - expected) * (counts[c] - expected) / expected;
    }
  }
  EXPECT_GT(chi2_wrong, boost::math::quantile(boost::math::chi_squared(kCells * kCells - 1), 1.0 - 1e-6));
}

const json kPlusDeterminismSpec =
    plus_spec(GenzParams{GenzFamily::discontinuous, {2.0, 3.0, 1.5}, {0.6, 0.4, 0.5}}, 17, 4096 * 63);

TEST(VegasPlus, OneAndTwoThreadsGiveIdenticalBits) {
  const auto one = testing::run_spec(kPlusDeterminismSpec, 1);
  const auto two = testing::run_spec(kPlusDeterminismSpec, 2);
  EXPECT_EQ(one->state().passes, 6u);
  expect_same_state(one->state(), two->state());
  const auto rep = vegas_report(one->state());
  ASSERT_TRUE(rep);
  EXPECT_EQ(rep->hypercubes, 10u * 10u * 10u);
}

// Checkpoints in the warm-up (passes 1, 2) and after it (4) carry the grid and the
// hypercube weights: resumed from their bytes, the run ends bit-identical.
TEST(VegasPlus, ResumeMidAdaptationIsBitIdentical) {
  const auto ref = testing::run_spec(kPlusDeterminismSpec, 2);
  for (uint64_t stop_after : {1, 2, 4}) {
    const testing::Interrupted first = testing::run_until_pass(kPlusDeterminismSpec, stop_after);
    ASSERT_FALSE(first.checkpoint.empty());
    expect_same_state(ref->state(), testing::resume_spec(kPlusDeterminismSpec, decode_checkpoint(first.checkpoint))->state());
  }
}

// Kernel states written by the codec before byte_codec (host byte order, on x86-64;
// tests/integrate/data, pass 2 of kDeterminismSpec / kPlusDeterminismSpec): they read,
// re-encode to the same bytes, and a job resumed from them ends bit-identical to the
// uninterrupted run.
TEST(VegasPlus, StatesOfTheOldCodecStillResume) {
  for (const auto& [spec, file] : {std::pair{&kDeterminismSpec, "vegas_state_v1.bin"},
                                   std::pair{&kPlusDeterminismSpec, "vegas_state_v2.bin"}}) {
    SCOPED_TRACE(file);
    std::ifstream in(std::string(TALLY_SOURCE_DIR "/tests/integrate/data/") + file, std::ios::binary);
    ASSERT_TRUE(in);
    const std::string stored((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    ASSERT_GT(stored.size(), 1000u);
    const testing::Interrupted now = testing::run_until_pass(*spec, 2);
    ASSERT_FALSE(now.checkpoint.empty());
    EXPECT_EQ(now.run->state().kernel_state, stored);  // the codec writes the old bytes
    JobState restored = decode_checkpoint(now.checkpoint);
    restored.kernel_state = stored;
    expect_same_state(testing::run_spec(*spec, 2)->state(), testing::resume_spec(*spec, std::move(restored))->state());
  }
}

// A sample limit that is not a whole number of rounds: the last pass is cut short,
// some hypercubes get fewer than 2 samples, and that pass is left out of the estimate
// (still within 4 sigma of the closed form).
TEST(VegasPlus, APassCutShortIsNotUsed) {
  const GenzParams p = instance(GenzFamily::gaussian, 2);
  const auto r = testing::run_spec(plus_spec(p, 4, 4096 * 15 + 1000), 1);
  EXPECT_EQ(r->state().samples, 4096u * 15 + 1000);
  const auto rep = vegas_report(r->state());
  ASSERT_TRUE(rep);
  ASSERT_EQ(rep->iterations.size(), 5u);
  EXPECT_TRUE(rep->iterations.back().warmup);  // not used
  EXPECT_EQ(rep->used, 1u);
  const Estimate e = r->headline();
  EXPECT_LE(std::fabs(e.mean - genz_exact(p)), 4.0 * e.std_error);
}

// Vector integrands with stratification: the allocation follows the sum of the
// components' normalised sigma_h^2; every component's combined estimate is within 4
// of its standard errors of its closed form.
TEST(VegasPlus, VectorComponentsMatchTheirClosedForms) {
  const std::vector<double> a = {4.0, 6.0, 3.0}, u = {0.3, 0.6, 0.45};
  const json spec = {{"kind", "integrate"},
                     {"seed", 8},
                     {"integrand", {{"builtin", "genz"}, {"families", {"gaussian", "product_peak", "discontinuous"}},
                                    {"a", a}, {"u", u}}},
                     {"estimator", {{"type", "vegas"}, {"stratify", true}}},
                     {"stop", {{"max_samples", 4096 * 31}}}};
  const auto r = testing::run_spec(spec, 2);
  const auto rep = vegas_report(r->state());
  ASSERT_TRUE(rep);
  ASSERT_EQ(rep->combined_mean.size(), 3u);
  const GenzFamily fams[] = {GenzFamily::gaussian, GenzFamily::product_peak, GenzFamily::discontinuous};
  for (size_t c = 0; c < 3; ++c) {
    const double exact = genz_exact(GenzParams{fams[c], a, u});
    EXPECT_LE(std::fabs(rep->combined_mean[c] - exact), 4.0 * rep->combined_std_error[c] * rep->error_scale)
        << c << " mean " << rep->combined_mean[c] << " exact " << exact;
    EXPECT_GT(rep->combined_std_error[c], 0.0);
  }
}

TEST(VegasPlus, BadSpecsNameTheField) {
  const GenzParams p = instance(GenzFamily::gaussian, 2);
  auto expect_pointer = [](const json& spec, const std::string& ptr) {
    try {
      compile_job(spec, JobLimits{});
      ADD_FAILURE() << "accepted " << spec.dump();
    } catch (const SpecError& e) {
      EXPECT_EQ(e.pointer(), ptr) << e.what();
    }
  };
  expect_pointer(vegas_spec(p, 1, 10000, {{"type", "vegas"}, {"stratify", true}, {"combine", "pooled"}}),
                 "/estimator/combine");
  expect_pointer(vegas_spec(p, 1, 10000, {{"type", "vegas"}, {"beta", 0.5}}), "/estimator/beta");
  expect_pointer(vegas_spec(p, 1, 10000, {{"type", "vegas"}, {"stratify", true}, {"beta", 1.5}}), "/estimator/beta");
  expect_pointer(vegas_spec(p, 1, 10000, {{"type", "vegas"}, {"stratify", "yes"}}), "/estimator/stratify");
}

}  // namespace
}  // namespace tally

