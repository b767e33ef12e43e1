// The VEGAS estimator (common/integrate/vegas.hpp): closed-form Genz checks in 1-8
// dimensions, the grid's sampling against its own density, bit-identity across
// thread counts and resumes in the middle of the adaptation, and the chi^2 warning.
#include <gtest/gtest.h>

#include <boost/math/distributions/chi_squared.hpp>
#include <cmath>

#include "common/engine/checkpoint.hpp"
#include "common/protocol/spec_reader.hpp"
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

void expect_same_state(const JobState& a, const JobState& b) {
  ASSERT_EQ(a.channels.size(), b.channels.size());
  for (size_t i = 0; i < a.channels.size(); ++i) EXPECT_EQ(a.channels[i], b.channels[i]) << i;
  EXPECT_EQ(a.samples, b.samples);
  EXPECT_EQ(a.passes, b.passes);
  EXPECT_EQ(a.counters, b.counters);
  EXPECT_EQ(a.kernel_state, b.kernel_state);  // the grid and every iteration, bit for bit
}

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
    auto job = compile_job(kDeterminismSpec, JobLimits{});
    JobRunner first(job->kernel(), job->stop_rule(), JobCaps{});
    std::string saved;
    std::atomic<bool> cancel{false};
    LocalRunOptions o;
    o.threads = 2;
    o.cancel = &cancel;
    o.on_pass = [&](const JobRunner& jr) {
      if (jr.state().passes == stop_after) {
        saved = encode_checkpoint(jr.state());
        cancel = true;
      }
    };
    run_local(first, o);
    ASSERT_FALSE(saved.empty());
    const JobState restored = decode_checkpoint(saved);
    EXPECT_EQ(restored.kernel_state, first.state().kernel_state);
    auto job2 = compile_job(kDeterminismSpec, JobLimits{});
    JobRunner resumed(job2->kernel(), job2->stop_rule(), JobCaps{}, restored);
    run_local(resumed, 1);
    expect_same_state(ref->state(), resumed.state());
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
  EXPECT_EQ(pointer_of(vector_spec({{"expressions", {kE1, kE2}}}, {{"type", "qmc"}})), "/estimator/type");
}

}  // namespace
}  // namespace tally
