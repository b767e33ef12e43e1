// The cone rule (common/integrate/cone_rule.hpp, `"estimator": {"type": "qmc", "error":
// "cone"}`): its Walsh transform against the definition, the doubling against a transform
// of all points at once, its bound against closed-form Genz integrals, the job's result
// (an error bound, no confidence interval), bit-identity across threads, and the fields a
// bad spec names. Its coverage over random instances is in tests/statistical.
#include <gtest/gtest.h>

#include <bit>
#include <cmath>
#include <complex>
#include <cstring>
#include <numbers>
#include <fmt/format.h>
#include <vector>

#include "common/integrate/cone_rule.hpp"
#include "common/integrate/genz.hpp"
#include "common/integrate/integration_counters.hpp"
#include "common/rng/counter_rng.hpp"
#include "common/sampling/sobol_burley.hpp"
#include "common/spec/spec_reader.hpp"
#include "integrate/run_support.hpp"

namespace tally {
namespace {

using nlohmann::json;

json genz_spec(const GenzParams& p, json stop, json est = {{"type", "qmc"}, {"error", "cone"}}) {
  return {{"kind", "integrate"},
          {"integrand", {{"builtin", "genz"}, {"family", genz_family_name(p.family)}, {"a", p.a}, {"u", p.u}}},
          {"estimator", std::move(est)},
          {"stop", std::move(stop)}};
}

// y_k = 2^-m sum_i (-1)^popcount(i & k) x_i, term by term.
TEST(ConeRule, WalshHadamardMatchesTheDefinition) {
  const size_t n = 64;
  std::vector<double> x(n), y(n);
  for (size_t i = 0; i < n; ++i) x[i] = SampleRng(stream_key(3, 0), i).uniform(0) - 0.3;
  y = x;
  walsh_hadamard_normalized(y);
  for (size_t k = 0; k < n; ++k) {
    double s = 0.0;
    for (size_t i = 0; i < n; ++i) s += (std::popcount(i & k) % 2 ? -1.0 : 1.0) * x[i];
    EXPECT_NEAR(y[k], s / n, 1e-15) << k;
  }
  std::vector<double> bad(3);
  EXPECT_THROW(walsh_hadamard_normalized(bad), std::invalid_argument);
}

// Values with a closed form: x_i = c + the Walsh function of index w (so coefficient w is
// 1, every other but 0 is 0). A constant has bound 0 and meets any target at once; a
// high index's coefficient is seen by the bound only once it falls in the summed band.
TEST(ConeRule, ConstantsAreExactAndTheBoundSumsTheRightBand) {
  ConeRuleOptions o;
  o.m_min = 6;
  o.m_max = 10;
  o.lag = 2;
  o.abs_error = 1e-12;
  uint64_t asked = 0;
  auto constant = [&](uint64_t first, uint64_t n, double* out) {
    asked += n;
    for (uint64_t i = 0; i < n; ++i) out[i] = 2.5 + 0.0 * static_cast<double>(first);
    return true;
  };
  ConeRuleResult r = run_cone_rule(o, constant);
  EXPECT_TRUE(r.met);
  EXPECT_EQ(r.m, 6u);
  EXPECT_EQ(asked, 64u);
  EXPECT_EQ(r.mean, 2.5);
  EXPECT_EQ(r.error_bound, 0.0);

  // Coefficients that fall with the index, c_k = 1 / (k + 1)^2, keep the order kappa as it
  // is; the bound at m = 6 with lag 2 is fudge * 2^-6 * (c_8 + ... + c_15).
  std::vector<double> c(64), x(64);
  for (size_t k = 0; k < 64; ++k) c[k] = 1.0 / static_cast<double>((k + 1) * (k + 1));
  for (size_t i = 0; i < 64; ++i) {
    for (size_t k = 0; k < 64; ++k) x[i] += (std::popcount(i & k) % 2 ? -1.0 : 1.0) * c[k];
  }
  double band = 0.0;
  for (size_t k = 8; k < 16; ++k) band += c[k];
  o.m_max = 6;
  r = run_cone_rule(o, [&](uint64_t first, uint64_t n, double* out) {
    std::copy(x.begin() + static_cast<std::ptrdiff_t>(first), x.begin() + static_cast<std::ptrdiff_t>(first + n), out);
    return true;
  });
  EXPECT_NEAR(r.mean, 1.0, 1e-14);
  EXPECT_NEAR(r.error_bound, o.fudge / 64.0 * band, 1e-15);
  EXPECT_FALSE(r.met);

  // Values near the largest double: the transform halves before it adds, so the mean is
  // exact and the bound 0 (0.5 * (a + c) would overflow to inf, the bound to NaN).
  o.m_max = 10;
  r = run_cone_rule(o, [](uint64_t, uint64_t n, double* out) {
    std::fill(out, out + n, 1.5e308);
    return true;
  });
  EXPECT_EQ(r.mean, 1.5e308);
  EXPECT_EQ(r.error_bound, 0.0);
  EXPECT_TRUE(r.met);

  // A callback that stops (a fault, an abandoned block) stops the rule.
  o.m_max = 10;
  o.abs_error = 0.0;  // no target: it would double to 2^10
  int calls = 0;
  r = run_cone_rule(o, [&](uint64_t, uint64_t n, double* out) {
    std::fill(out, out + n, 1.0);
    return ++calls < 2;
  });
  EXPECT_TRUE(r.aborted);
  EXPECT_EQ(calls, 2);
  EXPECT_THROW(run_cone_rule(ConeRuleOptions{.m_min = 4, .m_max = 10, .lag = 4}, constant), std::invalid_argument);
}

// Doubling (transform the new half, one more butterfly level) gives the same mean, bit for
// bit, as transforming all 2^m values at once: the same operations in the same order.
void expect_doubling_same_mean(ConeBasis basis) {
  auto f = [](uint64_t first, uint64_t n, double* out) {
    for (uint64_t i = 0; i < n; ++i) out[i] = std::exp(std::sin(0.37 * static_cast<double>(first + i)));
    return true;
  };
  ConeRuleOptions doubling;
  doubling.basis = basis;
  doubling.m_min = 8;
  doubling.m_max = 13;
  ConeRuleOptions once = doubling;
  once.m_min = 13;
  const ConeRuleResult a = run_cone_rule(doubling, f), b = run_cone_rule(once, f);
  EXPECT_EQ(a.m, 13u);
  EXPECT_EQ(std::memcmp(&a.mean, &b.mean, sizeof(double)), 0) << a.mean << " vs " << b.mean;
}

TEST(ConeRule, DoublingGivesTheSameMeanAsOneTransform) { expect_doubling_same_mean(ConeBasis::walsh); }

// The smooth Genz families in d = 4 and 8 at relative 1e-4: the job stops on its target,
// the bound is within it, and the closed form lies within the bound (`est`: either form).
void expect_smooth_genz_within_bound(const json& stop, const json& est) {
  for (size_t d : {4u, 8u}) {
    for (GenzFamily f : {GenzFamily::oscillatory, GenzFamily::product_peak, GenzFamily::corner_peak,
                         GenzFamily::gaussian}) {
      const GenzParams p = genz_random_instance(f, d, 7);
      const double exact = genz_exact(p);
      const auto r = testing::run_spec(genz_spec(p, stop, est));
      const std::string what = fmt::format("{} {} d={}", est["type"].get<std::string>(), genz_family_name(f), d);
      EXPECT_EQ(r->stop_reason(), StopReason::error_target) << what;
      const ErrorSummary e = r->error();
      EXPECT_LE(e.rel_error, 1e-4) << what;
      EXPECT_LE(std::fabs(e.mean - exact), e.abs_error) << what << " mean " << e.mean << " exact " << exact;
      const uint64_t evals = r->state().counters[IntegrationCounter::evaluations];
      EXPECT_TRUE(std::has_single_bit(evals) && evals >= 1024) << what << " " << evals;
    }
  }
}

TEST(ConeRule, SmoothGenzIntegralsLieWithinTheBound) {
  expect_smooth_genz_within_bound({{"rel_error", 1e-4}, {"max_samples", 1 << 22}}, {{"type", "qmc"}, {"error", "cone"}});
}

// The result says what the error is: a bound, no interval; one "rule" sample; the plan
// names the rule; bit-identical on 1 and 2 threads.
// Runs `spec` on 1 and 2 threads: the same mean and bound bit for bit, and a result with
// `error_estimate` (the bound) and no `ci`. Returns the 1-thread run.
testing::Ran expect_bound_bit_identical(const json& spec) {
  auto a = testing::run_spec(spec, 1);
  const auto b = testing::run_spec(spec, 2);
  const double ma = a->error().mean, mb = b->error().mean, ea = a->error().abs_error, eb = b->error().abs_error;
  EXPECT_EQ(std::memcmp(&ma, &mb, sizeof ma), 0);
  EXPECT_EQ(std::memcmp(&ea, &eb, sizeof ea), 0);
  const json res = kind_result_json(*a.job, *a.runner);
  EXPECT_TRUE(res.contains("error_estimate")) << res.dump();
  if (res.contains("error_estimate")) {
    EXPECT_EQ(res["error_estimate"].get<double>(), ea);
  }
  EXPECT_FALSE(res.contains("ci"));
  return a;
}

TEST(ConeRule, ReportsABoundBitIdentically) {
  const GenzParams p = genz_random_instance(GenzFamily::gaussian, 6, 3);
  const auto a = expect_bound_bit_identical(genz_spec(p, {{"rel_error", 1e-5}}));
  const json res = kind_result_json(*a.job, *a.runner);
  EXPECT_EQ(res["sample_unit"], "rule");
  EXPECT_NE(res["estimator"]["error"].get<std::string>().find("not a confidence interval"), std::string::npos);
  EXPECT_NE(res["estimator"]["rule"].get<std::string>().find("cone rule"), std::string::npos);

  // At the target 1 it stops at once, on 2^10 points.
  const auto cone = testing::run_spec(genz_spec(p, {{"rel_error", 1.0}}));
  EXPECT_EQ(cone->state().counters[IntegrationCounter::evaluations], 1024u);
  EXPECT_EQ(cone->stop_reason(), StopReason::error_target);
}

// Out of budget: the job stops at max_samples (the largest power of two within it) with
// the bound it has, and says the target was not met.
TEST(ConeRule, StopsAtTheBudgetWithTheBoundItHas) {
  const GenzParams p = genz_random_instance(GenzFamily::oscillatory, 16, 2);
  const auto r = testing::run_spec(genz_spec(p, {{"rel_error", 1e-12}, {"max_samples", 5000}}));
  EXPECT_EQ(r->state().counters[IntegrationCounter::evaluations], 4096u);
  EXPECT_EQ(r->stop_reason(), StopReason::max_samples);
  EXPECT_GT(r->error().abs_error, 0.0);
}

// A NaN fails the job naming the point and the rule's point set, like every other estimator.
void expect_nan_named(const json& est, const std::string& point_set) {
  const json spec = {{"kind", "integrate"},
                     {"integrand", {{"expression", "log(x0 - 0.5)"}}},
                     {"domain", {{"type", "interval"}, {"lower", 0.0}, {"upper", 1.0}}},
                     {"estimator", est},
                     {"stop", {{"rel_error", 1e-3}}}};
  const auto r = testing::run_spec(spec);
  EXPECT_EQ(r->stop_reason(), StopReason::failed);
  ASSERT_TRUE(r->error_message().has_value());
  EXPECT_NE(r->error_message()->find("NaN at x0 = "), std::string::npos) << *r->error_message();
  EXPECT_NE(r->error_message()->find("of the cone rule's " + point_set), std::string::npos) << *r->error_message();
}

TEST(ConeRule, ANanFailsTheJobWithThePoint) { expect_nan_named({{"type", "qmc"}, {"error", "cone"}}, "Sobol' set"); }

void expect_refused(const json& spec, const std::string& pointer, const std::string& words) {
  try {
    compile_job(spec, JobLimits{});
    ADD_FAILURE() << "accepted: " << spec.dump();
  } catch (const SpecError& e) {
    EXPECT_EQ(e.pointer(), pointer) << e.what();
    EXPECT_NE(std::string(e.what()).find(words), std::string::npos) << e.what();
  }
}

TEST(ConeRule, BadSpecsNameTheField) {
  const GenzParams p = genz_random_instance(GenzFamily::gaussian, 3, 1);
  expect_refused(genz_spec(p, {{"rel_error", 1e-4}}, {{"type", "qmc"}, {"error", "cone"}, {"points", 2048}}),
                 "/estimator/points", "takes no points");
  expect_refused(genz_spec(p, {{"rel_error", 1e-4}}, {{"type", "qmc"}, {"error", "cone"}, {"scramble", "owen"}}),
                 "/estimator/scramble", "takes no points");
  expect_refused(genz_spec(p, {{"rel_error", 1e-4}}, {{"type", "qmc"}, {"error", "bound"}}), "/estimator/error",
                 "randomizations");
  expect_refused(genz_spec(p, {{"rel_error", 1e-4}, {"max_samples", 100}}), "/stop/max_samples", "between 1024");
  expect_refused(genz_spec(p, {{"rel_error", 1e-4}, {"max_samples", uint64_t{1} << 30}}), "/stop/max_samples",
                 "16777216");
  const json vec = {{"kind", "integrate"},
                    {"integrand", {{"expressions", {"x0", "x0*x0"}}}},
                    {"domain", {{"type", "interval"}, {"lower", 0.0}, {"upper", 1.0}}},
                    {"estimator", {{"type", "qmc"}, {"error", "cone"}}},
                    {"stop", {{"rel_error", 1e-3}}}};
  expect_refused(vec, "/estimator/error", "scalar integrand");
}

// ---- The lattice form: `"estimator": {"type": "lattice", "error": "cone"}` ----

const json kLatticeCone = {{"type", "lattice"}, {"error", "cone"}};

// Values given in radical-inverse order (position p holds natural index bitreverse_m(p))
// come out as the normalised DFT of the natural order: y_k = 2^-m sum_j x_j e^{-2 pi i jk/n}.
TEST(LatticeConeRule, DftMatchesTheDefinition) {
  const size_t m = 6, n = size_t{1} << m;
  std::vector<double> x(n);
  for (size_t j = 0; j < n; ++j) x[j] = SampleRng(stream_key(5, 0), j).uniform(0) - 0.4;
  std::vector<std::complex<double>> y(n);
  for (size_t p = 0; p < n; ++p) y[p] = x[sobol_burley::reverse_bits(static_cast<uint32_t>(p)) >> (32 - m)];
  lattice_dft_normalized(y);
  for (size_t k = 0; k < n; ++k) {
    std::complex<double> s = 0.0;
    for (size_t j = 0; j < n; ++j) s += x[j] * std::polar(1.0, -2.0 * std::numbers::pi * double(j * k % n) / n);
    EXPECT_NEAR(std::abs(y[k] - s / double(n)), 0.0, 1e-15) << k;
  }
  std::vector<std::complex<double>> bad(6);
  EXPECT_THROW(lattice_dft_normalized(bad), std::invalid_argument);
}

TEST(LatticeConeRule, DoublingGivesTheSameMeanAsOneTransform) { expect_doubling_same_mean(ConeBasis::fourier); }

// A trigonometric polynomial whose frequencies the lattice does not alias (h . z != 0
// mod 2^m for every h in it) is integrated exactly whatever the shift: with z_1 = 1,
// 1 + cos(2 pi x0) has mean 1 on every level, unperiodized.
TEST(LatticeConeRule, IntegratesUnaliasedFrequenciesExactly) {
  const json spec = {{"kind", "integrate"},
                     {"seed", 17},
                     {"integrand", {{"expression", "1 + cos(6.283185307179586*x0) + 0*x1*x2"}}},
                     {"domain", {{"type", "box"}, {"lower", {0, 0, 0}}, {"upper", {1, 1, 1}}}},
                     {"estimator", {{"type", "lattice"}, {"error", "cone"}, {"periodize", "none"}}},
                     {"stop", {{"abs_error", 1e-9}}}};
  const auto r = testing::run_spec(spec);
  EXPECT_EQ(r->stop_reason(), StopReason::error_target);
  EXPECT_NEAR(r->error().mean, 1.0, 1e-13);
  EXPECT_LE(r->error().abs_error, 1e-9);
}

// The same through the embedded lattice and the baker's transform.
TEST(LatticeConeRule, SmoothGenzIntegralsLieWithinTheBound) {
  expect_smooth_genz_within_bound({{"rel_error", 1e-4}}, kLatticeCone);
}

// The plan names the rule and the lattice; the same bits on 1 and 2 threads; a smaller
// cap takes the first points of the same lattice (the same mean where both stop).
TEST(LatticeConeRule, ReportsABoundBitIdentically) {
  const GenzParams p = genz_random_instance(GenzFamily::gaussian, 6, 3);
  const auto a = expect_bound_bit_identical(genz_spec(p, {{"rel_error", 1e-6}}, kLatticeCone));
  const double ma = a->error().mean;
  const json res = kind_result_json(*a.job, *a.runner);
  EXPECT_NE(res["estimator"]["rule"].get<std::string>().find("cubLattice_g"), std::string::npos);
  EXPECT_NE(res["estimator"]["construction"].get<std::string>().find("embedded rank-1 lattice"), std::string::npos);
  EXPECT_EQ(res["estimator"]["generating_vector"].size(), 6u);
  EXPECT_EQ(res["estimator"]["periodize"], "baker");

  const uint64_t used = a->state().counters[IntegrationCounter::evaluations];
  const auto capped = testing::run_spec(genz_spec(p, {{"rel_error", 1e-6}, {"max_samples", used}}, kLatticeCone));
  const double mc = capped->error().mean;
  EXPECT_EQ(std::memcmp(&ma, &mc, sizeof ma), 0);
}

TEST(LatticeConeRule, BadSpecsNameTheField) {
  const GenzParams p = genz_random_instance(GenzFamily::gaussian, 3, 1);
  expect_refused(genz_spec(p, {{"rel_error", 1e-4}}, {{"type", "lattice"}, {"error", "cone"}, {"points", 2048}}),
                 "/estimator/points", "takes no points");
  expect_refused(genz_spec(p, {{"rel_error", 1e-4}}, {{"type", "lattice"}, {"error", "cones"}}), "/estimator/error",
                 "randomizations");
  expect_refused(genz_spec(p, {{"rel_error", 1e-4}, {"max_samples", 1000}}, kLatticeCone), "/stop/max_samples",
                 "between 1024");
  expect_refused(genz_spec(p, {{"rel_error", 1e-4}, {"max_samples", (1 << 20) + 1}}, kLatticeCone),
                 "/stop/max_samples", "1048576");
  expect_refused(genz_spec(p, {{"rel_error", 1e-4}}, {{"type", "lattice"}, {"error", "cone"}, {"weights", -1}}),
                 "/estimator/weights", "");
  const GenzParams big = genz_random_instance(GenzFamily::gaussian, 33, 1);
  expect_refused(genz_spec(big, {{"rel_error", 1e-4}}, kLatticeCone), "/estimator/error", "at most 32 dimensions");
  // A deployment (or the fuzz harness) may lower the construction's dimensions.
  JobLimits small;
  small.max_embedded_lattice_dimensions = 2;
  try {
    compile_job(genz_spec(p, {{"rel_error", 1e-4}}, kLatticeCone), small);
    ADD_FAILURE() << "a 3-dimensional lattice cone rule was accepted with a limit of 2";
  } catch (const SpecError& e) {
    EXPECT_EQ(e.pointer(), "/estimator/error");
    EXPECT_NE(std::string(e.what()).find("at most 2 dimensions"), std::string::npos) << e.what();
  }
  const json vec = {{"kind", "integrate"},
                    {"integrand", {{"expressions", {"x0", "x0*x0"}}}},
                    {"domain", {{"type", "interval"}, {"lower", 0.0}, {"upper", 1.0}}},
                    {"estimator", kLatticeCone},
                    {"stop", {{"rel_error", 1e-3}}}};
  expect_refused(vec, "/estimator/error", "scalar integrand");
}

TEST(LatticeConeRule, ANanFailsTheJobWithThePoint) { expect_nan_named(kLatticeCone, "lattice"); }

}  // namespace
}  // namespace tally
