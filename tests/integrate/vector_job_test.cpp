// Many integrands in one job (issue 31): vector integrands on the lattice and qmc point
// sets, parameterized expressions (one template, thousands of values), state linear in
// the component count, and the components summary the stop rule's target reads against.
#include <gtest/gtest.h>

#include <cmath>
#include <string>
#include <vector>

#include <fmt/format.h>

#include "common/integrate/integration_job.hpp"
#include "common/protocol/integration_json.hpp"
#include "integrate/run_support.hpp"

namespace tally {
namespace {

using nlohmann::json;
using testing::run_spec;
using testing::unit_box;
using testing::spec_error_pointer;

json job(json integrand, json estimator, size_t d, json stop = {{"max_samples", 16}}) {
  return {{"kind", "integrate"},  {"seed", 11},           {"integrand", std::move(integrand)},
          {"domain", unit_box(d)}, {"estimator", estimator}, {"stop", std::move(stop)}};
}

IntegrationResult result_of(const testing::Ran& r) {
  return dynamic_cast<const IntegrationJob&>(*r.job).result(*r.runner);
}

// Every component is averaged over the same point sets as the scalar job of its function
// with the same seed: the tallies are equal bit for bit, so the scalar estimators'
// coverage tests (lattice_coverage_test, the QMC ones) hold for each component.
TEST(VectorJobs, LatticeAndQmcComponentsAreBitIdenticalToTheirScalarJobs) {
  const std::vector<std::string> fs = {"exp(-x0*x1)*cos(x2+x7)", "x0*x1*x2*x3*x4*x5*x6*x7", "1/(1+x0+x3+x5)"};
  const std::vector<json> ests = {{{"type", "lattice"}, {"points", 251}},
                                  {{"type", "qmc"}, {"points", 256}}};
  for (const json& est : ests) {
    const auto vec = run_spec(job({{"expressions", fs}}, est, 8), 2);
    ASSERT_EQ(vec->state().channels.size(), 3u + 3u) << est;  // 3 components + 3 pairs (m <= 64)
    for (size_t c = 0; c < fs.size(); ++c) {
      const auto one = run_spec(job({{"expression", fs[c]}}, est, 8), 1);
      EXPECT_EQ(vec->state().channels[c], one->state().channels[0]) << est << " component " << c;
    }
  }
}

// prod_j exp(-a x_j) over [0,1]^8 = ((1 - e^-a) / a)^8 for 200 values of a, one lattice
// job. z = (mean - exact) / std_error follows Student t with 15 degrees of freedom (16
// shifts); P(|t_15| > 7) = 4.4e-6 per component, so with 200 components (Bonferroni,
// whatever their correlation) the false-failure rate is below 1e-3.
TEST(VectorJobs, ParameterizedLatticeJobMeetsEveryClosedFormWithinItsErrorBar) {
  std::vector<double> a;
  for (int i = 0; i < 200; ++i) a.push_back(0.1 + 0.01 * i);
  const json integrand = {{"expression", "exp(-a*(x0+x1+x2+x3+x4+x5+x6+x7))"}, {"parameters", {{"a", a}}}};
  const auto r = run_spec(job(integrand, {{"type", "lattice"}, {"points", 1021}}, 8), 2);
  const IntegrationResult res = result_of(r);
  ASSERT_EQ(res.components.size(), a.size());
  EXPECT_TRUE(res.covariance_of_means.empty());  // 200 > 64 components: not kept unless asked
  EXPECT_EQ(r->state().channels.size(), a.size());
  for (size_t c = 0; c < a.size(); ++c) {
    const double exact = std::pow((1.0 - std::exp(-a[c])) / a[c], 8);
    const ComponentEstimate& e = res.components[c];
    ASSERT_GT(e.std_error, 0.0) << c;
    EXPECT_LT(std::fabs(e.mean - exact) / e.std_error, 7.0) << "a = " << a[c];
  }
  // The CLI's one line is about the vector: the count and the worst component.
  const std::string line = r.job->summary_line(*r.runner);
  EXPECT_EQ(line.rfind("200 components; worst: component ", 0), 0u) << line;
  // The result names the template and its values, not 200 bound texts.
  const json j = integration_result_json(res);
  EXPECT_EQ(j["integrand"]["expression"], integrand["expression"]);
  EXPECT_EQ(j["integrand"]["parameters"]["a"].size(), a.size());
  EXPECT_FALSE(j["integrand"].contains("expressions"));
}

// Binding substitutes the value's exact literal: a template with parameters is the same
// job, bit for bit, as the expressions written out.
TEST(VectorJobs, ParametersBindExactlyLikeTheWrittenOutExpressions) {
  const json est = {{"type", "uniform"}};
  const double v0 = 0.1, v1 = 1.0 / 3.0;
  const auto bound =
      run_spec(job({{"expression", "exp(-k*x0)*b + k"}, {"parameters", {{"k", {v0, v1}}, {"b", {2, -1.5}}}}},
                   est, 2, {{"max_samples", 20000}}));
  const auto written = run_spec(job({{"expressions",
                                      {fmt::format("exp(-({:.17g})*x0)*(2) + ({:.17g})", v0, v0),
                                       fmt::format("exp(-({:.17g})*x0)*(-1.5) + ({:.17g})", v1, v1)}}},
                                    est, 2, {{"max_samples", 20000}}));
  testing::expect_same_state(bound->state(), written->state());
}

// 10,000 components: the state is one tally per component (no pair channels), the
// result has every component and a summary; the worst component is the one the summary
// names. Integrand x0^p over [0,1]: exact 1/(p+1).
TEST(VectorJobs, TenThousandComponentsKeepStateLinearAndSummarise) {
  std::vector<double> p;
  for (int i = 0; i < 10000; ++i) p.push_back(0.5 + 0.001 * i);
  const json integrand = {{"expression", "x0^p"}, {"parameters", {{"p", p}}}};
  const auto r = run_spec(job(integrand, {{"type", "lattice"}, {"points", 101}}, 1,
                              {{"max_samples", 32}, {"rel_error", 1e-3}, {"min_samples", 16}}),
                          2);
  EXPECT_EQ(r->state().channels.size(), p.size());
  const IntegrationResult res = result_of(r);
  ASSERT_EQ(res.components.size(), p.size());
  ASSERT_TRUE(res.components_summary);
  const ComponentsSummary& s = *res.components_summary;
  EXPECT_EQ(s.count, p.size());
  // Recount independently: half-width / |mean| <= 1e-3.
  uint64_t met = 0;
  size_t worst = 0;
  double worst_rel = -1;
  for (size_t c = 0; c < p.size(); ++c) {
    const auto& e = res.components[c];
    const double rel = 0.5 * (e.ci_hi - e.ci_lo) / std::fabs(e.mean);
    met += rel <= 1e-3 ? 1 : 0;
    if (rel > worst_rel) {
      worst_rel = rel;
      worst = c;
    }
  }
  ASSERT_TRUE(s.met);
  EXPECT_EQ(*s.met, met);
  EXPECT_EQ(s.worst, worst);
  EXPECT_DOUBLE_EQ(s.worst_rel_half_width, worst_rel);
  // The job stops at its error target only when every component meets it.
  if (r->stop_reason() == StopReason::error_target) {
    EXPECT_EQ(met, p.size());
  }
}

TEST(VectorJobs, BadVectorSpecsNameTheField) {
  const json lat = {{"type", "lattice"}};
  EXPECT_EQ(spec_error_pointer(job({{"expression", "sin(x0)"}, {"parameters", {{"sin", {1, 2}}}}}, lat, 1)),
            "/integrand/parameters/sin");
  EXPECT_EQ(spec_error_pointer(job({{"expression", "x0"}, {"parameters", {{"x3", {1, 2}}}}}, lat, 1)),
            "/integrand/parameters/x3");
  EXPECT_EQ(spec_error_pointer(job({{"expression", "a*b*x0"}, {"parameters", {{"a", {1, 2}}, {"b", {1}}}}}, lat, 1)),
            "/integrand/parameters/b");
  EXPECT_EQ(spec_error_pointer(job({{"expression", "a*x0"}, {"parameters", {{"a", {1, "2"}}}}}, lat, 1)),
            "/integrand/parameters/a/1");
  EXPECT_EQ(spec_error_pointer(job({{"expression", "a*x0"}, {"parameters", json::object()}}, lat, 1)),
            "/integrand/parameters");
  EXPECT_EQ(spec_error_pointer(job({{"expressions", {"x0", "x0"}}, {"parameters", {{"a", {1, 2}}}}}, lat, 1)),
            "/integrand/parameters");
  // A name the template does not know is the template's error.
  EXPECT_EQ(spec_error_pointer(job({{"expression", "a*c*x0"}, {"parameters", {{"a", {1, 2}}}}}, lat, 1)),
            "/integrand/expression");
  // Limits: components, the covariance's channels, vegas's per-component grid sums.
  EXPECT_EQ(spec_error_pointer(
                job({{"expression", "a*x0"}, {"parameters", {{"a", std::vector<double>(16385, 1.0)}}}}, lat, 1)),
            "/integrand/parameters/a");
  EXPECT_EQ(spec_error_pointer(job({{"expression", "a*x0"},
                                    {"parameters", {{"a", std::vector<double>(16000, 1.0)}}},
                                    {"covariance", true}},
                                   lat, 1)),
            "/integrand/covariance");
  EXPECT_EQ(spec_error_pointer(
                job({{"expression", "a*x0"}, {"parameters", {{"a", std::vector<double>(65, 1.0)}}}}, {{"type", "vegas"}}, 1)),
            "/estimator/type");
  EXPECT_EQ(spec_error_pointer(
                job({{"expression", "a*x0"}, {"parameters", {{"a", std::vector<double>(64, 1.0)}}}}, {{"type", "vegas"}}, 1)),
            "<accepted>");
}

// covariance: false drops the pair channels of a small vector; true keeps them for a large one.
TEST(VectorJobs, CovarianceIsKeptExactlyWhenAsked) {
  const json est = {{"type", "lattice"}, {"points", 31}};
  const auto off = run_spec(job({{"expressions", {"x0", "x0*x0", "x0^3"}}, {"covariance", false}}, est, 1));
  EXPECT_EQ(off->state().channels.size(), 3u);
  EXPECT_TRUE(result_of(off).covariance_of_means.empty());
  std::vector<double> a(70);
  for (size_t i = 0; i < a.size(); ++i) a[i] = static_cast<double>(i);
  const auto on = run_spec(job({{"expression", "x0^a"}, {"parameters", {{"a", a}}}, {"covariance", true}}, est, 1));
  EXPECT_EQ(on->state().channels.size(), 70u + 70u * 69u / 2u);
  const IntegrationResult res = result_of(on);
  ASSERT_EQ(res.covariance_of_means.size(), 70u);
  // Component 0 is x0^0 = 1 exactly: no variance, so no covariance with anything (up to
  // the rounding of var(1 + f) against var(f)).
  EXPECT_NEAR(res.covariance_of_means[0][5], 0.0, 1e-9 * res.covariance_of_means[5][5]);
  EXPECT_GT(res.covariance_of_means[1][2], 0.0);  // x0 and x0^2 rise together
}

}  // namespace
}  // namespace tally
