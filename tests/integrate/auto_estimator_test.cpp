// `"estimator": {"type": "auto"}` (issue 31): a pilot of uniform, qmc and the lattice
// (baker, none) picks the candidate with the fewest predicted evaluations to the
// target (for a vector integrand, every component's), deterministically, and the plan
// says what it chose and why.
#include <gtest/gtest.h>

#include <algorithm>
#include <boost/math/special_functions/bessel.hpp>
#include <cmath>
#include <fmt/format.h>

#include "common/engine/stop_rule.hpp"
#include "common/integrate/auto_estimator.hpp"
#include "common/integrate/domain.hpp"
#include "common/integrate/genz.hpp"
#include "common/integrate/lattice_rule.hpp"
#include "common/integrate/integration_job.hpp"
#include "common/protocol/integration_json.hpp"
#include "common/spec/spec_reader.hpp"
#include "integrate/run_support.hpp"

namespace tally {
namespace {

using nlohmann::json;
using testing::run_spec;
using testing::unit_box;

const EstimatorPlan& plan_of(const JobDefinition& job) { return dynamic_cast<const IntegrationJob&>(job).plan().estimator; }

// A smooth periodic integrand (d = 8) to 6 digits: the unperiodized lattice wins
// (baker's fold would add a kink), and the job then meets the target with an interval
// that contains the closed form.
TEST(AutoEstimator, PicksTheUnperiodizedLatticeForASmoothPeriodicIntegrand) {
  const size_t d = 8;
  std::string f;
  double exact = 1.0;
  for (size_t j = 0; j < d; ++j) {
    const double c = 1.0 / static_cast<double>(j + 1);
    f += fmt::format("{}{:.17g}*sin(2*_pi*x{})", j ? "+" : "", c, j);
    exact *= boost::math::cyl_bessel_i(0, c);
  }
  const json spec = {{"kind", "integrate"},
                     {"seed", 4},
                     {"integrand", {{"expression", "exp(" + f + ")"}}},
                     {"domain", unit_box(d)},
                     {"estimator", {{"type", "auto"}}},
                     {"stop", {{"rel_error", 1e-6}, {"max_samples", 100000}}}};
  const auto r = run_spec(spec);
  const EstimatorPlan& p = plan_of(*r.job);
  ASSERT_TRUE(p.selection.has_value());
  const AutoSelection& s = *p.selection;
  ASSERT_EQ(s.candidates.size(), 4u);
  const AutoCandidate& w = s.candidates[s.chosen];
  std::printf("%s\n", s.reason.c_str());
  EXPECT_EQ(p.type, "lattice");
  EXPECT_EQ(w.estimator, "lattice");
  EXPECT_EQ(w.periodize, "none");
  EXPECT_EQ(p.periodize, "none");
  EXPECT_EQ(p.points_per_sample, w.points);
  for (const AutoCandidate& c : s.candidates) EXPECT_LE(w.predicted_evaluations, c.predicted_evaluations);
  EXPECT_GT(s.candidates[0].predicted_evaluations, 1000.0 * w.predicted_evaluations);  // uniform
  EXPECT_NE(s.reason.find("lattice (none)"), std::string::npos) << s.reason;
  // A cheap job: two pilot sizes only (16,384 uniform + 3 x 8 x (1024 + 8192) points).
  for (size_t i = 1; i < s.candidates.size(); ++i) EXPECT_EQ(s.candidates[i].pilot_points.size(), 2u);
  EXPECT_EQ(s.pilot_evaluations, 16384u + 8u * (1024u + 8192u) + 2u * 8u * (1021u + 8191u));
  EXPECT_EQ(r->stop_reason(), StopReason::error_target);
  const Estimate e = r->estimate(0);
  EXPECT_LE(e.ci_lo, exact);
  EXPECT_GE(e.ci_hi, exact);
  // The protocol layer renders the choice with the plan.
  const json j = integration_plan_json(dynamic_cast<const IntegrationJob&>(*r.job).plan());
  EXPECT_EQ(j["estimator"]["type"], "lattice");
  EXPECT_EQ(j["estimator"]["auto"]["chosen"], s.chosen);
  EXPECT_EQ(j["estimator"]["auto"]["reason"], s.reason);
  EXPECT_EQ(j["estimator"]["auto"]["candidates"].size(), 4u);
}

// A non-periodic Genz gaussian (d = 8) at 5e-6: a randomized QMC estimator, never
// plain Monte Carlo; the same spec always makes the same choice (workers and resumed
// jobs compile it again), and a different seed's pilot may differ only in its numbers.
TEST(AutoEstimator, ChoiceIsDeterministicAndNeverPlainMonteCarloOnASmoothIntegrand) {
  const GenzParams p = genz_random_instance(GenzFamily::gaussian, 8, 1);
  const json spec = {{"kind", "integrate"},
                     {"seed", 7},
                     {"integrand", {{"builtin", "genz"}, {"family", "gaussian"}, {"a", p.a}, {"u", p.u}}},
                     {"estimator", {{"type", "auto"}}},
                     {"stop", {{"rel_error", 5e-6}}}};
  const auto a = compile_job(spec, JobLimits{});
  const auto b = compile_job(spec, JobLimits{});
  const AutoSelection& sa = *plan_of(*a).selection;
  const AutoSelection& sb = *plan_of(*b).selection;
  EXPECT_EQ(sa.chosen, sb.chosen);
  EXPECT_EQ(sa.reason, sb.reason);
  EXPECT_NE(plan_of(*a).type, "uniform");
  std::printf("%s\n", sa.reason.c_str());
}

// A Genz gaussian at d = 12 to 5 digits costs tens of millions of evaluations: the
// pilot fits each candidate's rate again between 2^13 and 2^16 points (a rate fitted on
// small sets alone chose a lattice that ran out of time on such instances, docs/
// accuracy-vs-time.md section 9), then the chosen estimator meets the target with an
// interval that contains the closed form.
TEST(AutoEstimator, ALargeJobFitsItsRateAgainAtATwoToTheSixteenPointPilot) {
  const GenzParams p = genz_random_instance(GenzFamily::gaussian, 12, 1);
  const double exact = genz_exact(p);
  const json spec = {{"kind", "integrate"},
                     {"seed", 1},
                     {"integrand", {{"builtin", "genz"}, {"family", "gaussian"}, {"a", p.a}, {"u", p.u}}},
                     {"estimator", {{"type", "auto"}}},
                     {"stop", {{"rel_error", 5e-6}, {"max_samples", 100000}}}};
  const auto r = run_spec(spec);
  const EstimatorPlan& plan = plan_of(*r.job);
  const AutoSelection& s = *plan.selection;
  std::printf("%s\n", s.reason.c_str());
  uint64_t refine = 0;
  for (size_t i = 1; i < s.candidates.size(); ++i) {
    const AutoCandidate& c = s.candidates[i];
    ASSERT_EQ(c.pilot_points.size(), 3u) << c.estimator;
    ASSERT_EQ(c.pilot_sd.size(), 3u);
    EXPECT_EQ(c.pilot_points[2], c.estimator == "qmc" ? 65536u : 65521u);
    refine += 8 * c.pilot_points[2];
    // The rate comes from the two largest sizes.
    const double fitted = std::log(c.pilot_sd[1] / c.pilot_sd[2]) /
                          std::log(static_cast<double>(c.pilot_points[2]) / static_cast<double>(c.pilot_points[1]));
    EXPECT_DOUBLE_EQ(c.rate, std::clamp(fitted, 0.5, 1.5)) << c.estimator;
  }
  EXPECT_EQ(s.pilot_evaluations, 16384u + 8u * (1024u + 8192u) + 2u * 8u * (1021u + 8191u) + refine);
  const AutoCandidate& w = s.candidates[s.chosen];
  EXPECT_GE(w.predicted_evaluations, 4.0 * static_cast<double>(refine));
  EXPECT_EQ(plan.points_per_sample, w.points);
  EXPECT_EQ(r->stop_reason(), StopReason::error_target);
  const Estimate e = r->estimate(0);
  EXPECT_LE(e.ci_lo, exact);
  EXPECT_GE(e.ci_hi, exact);
  EXPECT_LE(std::fabs(e.mean - exact), 5e-6 * exact);
}

// The pilot hands out the lattice rules it built, one per pilot size, each the rule CBC
// builds for that size with the default weights; a spec whose choice is a lattice of a
// pilot size (here the third, 65,521 points) compiles to that rule, taken from the pilot
// rather than constructed a second time (integration_spec.cpp).
TEST(AutoEstimator, ThePilotsLatticeRulesAreCbcsAndAChosenOneIsReused) {
  // The instance of ChoiceIsDeterministic...: auto chooses the baker lattice at the third
  // pilot size.
  const GenzParams p = genz_random_instance(GenzFamily::gaussian, 8, 1);
  const std::vector<double> weights(8, kDefaultLatticeWeight);
  IntegrationProblem prob;
  prob.integrand = make_genz(p);
  prob.domain = make_box(std::vector<double>(8, 0.0), std::vector<double>(8, 1.0));
  prob.seed = 7;
  StopRule stop;
  stop.rel_error = 5e-6;
  PilotLatticeRules rules;
  const AutoSelection s = select_estimator(prob, stop, &rules);
  std::vector<uint32_t> sizes;
  for (const auto& [n, rule] : rules) {
    sizes.push_back(n);
    const LatticeRule fresh = cbc_lattice_rule(n, weights);
    EXPECT_EQ(rule.n, n);
    EXPECT_EQ(rule.z, fresh.z) << n;
    EXPECT_EQ(rule.worst_case_error, fresh.worst_case_error) << n;
  }
  EXPECT_EQ(sizes, (std::vector<uint32_t>{1021, 8191, 65521}));
  // Without the out-parameter the selection is the same.
  const AutoSelection again = select_estimator(prob, stop);
  EXPECT_EQ(again.chosen, s.chosen);
  EXPECT_EQ(again.reason, s.reason);

  const json spec = {{"kind", "integrate"},
                     {"seed", 7},
                     {"integrand", {{"builtin", "genz"}, {"family", "gaussian"}, {"a", p.a}, {"u", p.u}}},
                     {"estimator", {{"type", "auto"}}},
                     {"stop", {{"rel_error", 5e-6}}}};
  const EstimatorPlan chosen = plan_of(*compile_job(spec, JobLimits{}));
  ASSERT_EQ(chosen.type, "lattice") << chosen.selection->reason;
  ASSERT_EQ(chosen.points_per_sample, 65521u);  // a pilot size: its rule is the pilot's
  const LatticeRule fresh = cbc_lattice_rule(65521, weights);
  EXPECT_EQ(chosen.generating_vector, std::vector<uint64_t>(fresh.z.begin(), fresh.z.end()));
  EXPECT_EQ(chosen.worst_case_error, fresh.worst_case_error);
}

// A spec compiled again in the same process takes its pilot's remembered answer
// (select_estimator_remembered): no second pilot, the same plan, the same kernel bits.
// A spec that differs in its seed or its target runs its own pilot, and an answer
// pushed out by kSelectionMemoEntries newer ones is piloted again.
TEST(AutoEstimator, ASpecCompiledAgainReusesItsPilot) {
  const GenzParams p = genz_random_instance(GenzFamily::gaussian, 8, 1);
  json spec = {{"kind", "integrate"},
               {"seed", 11},
               {"integrand", {{"builtin", "genz"}, {"family", "gaussian"}, {"a", p.a}, {"u", p.u}}},
               {"estimator", {{"type", "auto"}}},
               {"stop", {{"rel_error", 5e-6}}}};
  const auto block_of = [](const JobDefinition& job) {
    Block b;
    b.sample_count = 2;
    BlockResult out;
    job.kernel()->run_block(b, out);
    return std::pair(out.tallies.at(0).mean, out.tallies.at(0).m2);
  };
  const uint64_t before = pilots_run();
  const auto first = compile_job(spec, JobLimits{});
  EXPECT_EQ(pilots_run(), before + 1);
  const auto second = compile_job(spec, JobLimits{});
  EXPECT_EQ(pilots_run(), before + 1) << "the second compile ran the pilot again";
  EXPECT_EQ(estimator_plan_json(plan_of(*second)), estimator_plan_json(plan_of(*first)));
  EXPECT_EQ(plan_of(*second).type, "lattice");  // with the rule the memo kept
  EXPECT_EQ(block_of(*second), block_of(*first));

  json other_seed = spec;
  other_seed["seed"] = 12;
  compile_job(other_seed, JobLimits{});
  EXPECT_EQ(pilots_run(), before + 2);
  json other_target = spec;
  other_target["stop"]["rel_error"] = 1e-5;
  compile_job(other_target, JobLimits{});
  EXPECT_EQ(pilots_run(), before + 3);

  // kSelectionMemoEntries cheap specs (d = 2, 3 digits: no third pilot size) push the
  // first answer out.
  for (size_t i = 0; i < kSelectionMemoEntries; ++i) {
    const json cheap = {{"kind", "integrate"},
                        {"seed", 1000 + i},
                        {"integrand", {{"expression", "x0*x1"}}},
                        {"domain", unit_box(2)},
                        {"estimator", {{"type", "auto"}}},
                        {"stop", {{"rel_error", 1e-3}}}};
    compile_job(cheap, JobLimits{});
  }
  EXPECT_EQ(pilots_run(), before + 3 + kSelectionMemoEntries);
  const auto third = compile_job(spec, JobLimits{});
  EXPECT_EQ(pilots_run(), before + 4 + kSelectionMemoEntries);
  EXPECT_EQ(estimator_plan_json(plan_of(*third)), estimator_plan_json(plan_of(*first)));
}

// exp(s * sum_j sin(2 pi x_j) / (j + 1)) over [0,1]^d, = prod_j I0(s / (j + 1)).
std::string periodic_template(size_t d) {
  std::string f;
  for (size_t j = 0; j < d; ++j) f += fmt::format("{}{:.17g}*sin(2*_pi*x{})", j ? "+" : "", 1.0 / (j + 1.0), j);
  return "exp(s*(" + f + "))";
}
double periodic_exact(size_t d, double s) {
  double e = 1.0;
  for (size_t j = 0; j < d; ++j) e *= boost::math::cyl_bessel_i(0, s / (j + 1.0));
  return e;
}

// A vector integrand is predicted per component against its own target, and a point
// set costs what its neediest component needs: at one relative target the largest s
// (the widest spread) sets the cost; a looser component target on it (1e-2) moves the
// cost to the next one. The job then meets every component's target with intervals that hold
// the closed forms.
TEST(AutoEstimator, AVectorIntegrandIsPredictedByItsNeediestComponent) {
  const size_t d = 8;
  const std::vector<double> s = {0.1, 0.5, 1.0};
  const json base = {{"kind", "integrate"},
                     {"seed", 3},
                     {"integrand", {{"expression", periodic_template(d)}, {"parameters", {{"s", s}}}}},
                     {"domain", unit_box(d)},
                     {"estimator", {{"type", "auto"}}},
                     {"stop", {{"rel_error", 1e-6}, {"max_samples", 100000}}}};
  {
    const auto job = compile_job(base, JobLimits{});
    const AutoSelection& sel = *plan_of(*job).selection;
    std::printf("%s\n", sel.reason.c_str());
    EXPECT_EQ(sel.components, 3u);
    for (size_t i = 1; i < sel.candidates.size(); ++i) EXPECT_EQ(sel.candidates[i].limiting_component, 2u);
    EXPECT_NE(sel.reason.find("component 2's"), std::string::npos) << sel.reason;
    const json j = integration_plan_json(dynamic_cast<const IntegrationJob&>(*job).plan());
    EXPECT_EQ(j["estimator"]["auto"]["candidates"][1]["limiting_component"], 2);
  }
  json tight = base;
  tight["stop"]["component_targets"] = {{"rel_error", {nullptr, nullptr, 1e-2}}};
  const auto r = run_spec(tight);
  const EstimatorPlan& plan = plan_of(*r.job);
  const AutoSelection& sel = *plan.selection;
  std::printf("%s\n", sel.reason.c_str());
  const AutoCandidate& w = sel.candidates[sel.chosen];
  EXPECT_EQ(w.limiting_component, 1u);
  EXPECT_NE(sel.reason.find("component 1's"), std::string::npos) << sel.reason;
  EXPECT_NE(w.estimator, "uniform");
  EXPECT_EQ(plan.points_per_sample, w.points);
  EXPECT_NEAR(sel.target_half_width, 1e-6 * periodic_exact(d, 0.5), 1e-9);
  EXPECT_EQ(r->stop_reason(), StopReason::error_target);
  for (size_t c = 0; c < s.size(); ++c) {
    const Estimate e = r->estimate(c);
    const double exact = periodic_exact(d, s[c]);
    EXPECT_LE(e.ci_lo, exact) << c;
    EXPECT_GE(e.ci_hi, exact) << c;
    EXPECT_LE(0.5 * (e.ci_hi - e.ci_lo), (c == 2 ? 1e-2 : 1e-6) * exact) << c;
  }
}

// Each component of a vector job is averaged over the same point sets as its scalar job
// (VectorJobs.LatticeAndQmcComponentsAreBitIdenticalToTheirScalarJobs), so a vector of
// two copies of a scalar integrand has the scalar's randomized-QMC pilot exactly, and the
// same choice.
TEST(AutoEstimator, AVectorOfCopiesChoosesAsItsScalarDoes) {
  const GenzParams p = genz_random_instance(GenzFamily::gaussian, 8, 1);
  std::string f;
  for (size_t j = 0; j < p.a.size(); ++j) {
    f += fmt::format("{}{:.17g}^2*(x{}-{:.17g})^2", j ? "+" : "", p.a[j], j, p.u[j]);
  }
  f = "exp(-(" + f + "))";
  json scalar = {{"kind", "integrate"},
                 {"seed", 7},
                 {"integrand", {{"expression", f}}},
                 {"domain", unit_box(p.a.size())},
                 {"estimator", {{"type", "auto"}}},
                 {"stop", {{"rel_error", 1e-5}}}};
  json vector = scalar;
  vector["integrand"] = {{"expressions", {f, f}}};
  const auto a = compile_job(scalar, JobLimits{});
  const auto b = compile_job(vector, JobLimits{});
  const AutoSelection& sa = *plan_of(*a).selection;
  const AutoSelection& sb = *plan_of(*b).selection;
  std::printf("%s\n%s\n", sa.reason.c_str(), sb.reason.c_str());
  ASSERT_EQ(sa.candidates.size(), sb.candidates.size());
  for (size_t i = 1; i < sa.candidates.size(); ++i) {
    EXPECT_EQ(sa.candidates[i].pilot_sd, sb.candidates[i].pilot_sd) << i;
    EXPECT_EQ(sa.candidates[i].predicted_evaluations, sb.candidates[i].predicted_evaluations) << i;
    EXPECT_EQ(sa.candidates[i].points, sb.candidates[i].points) << i;
  }
  EXPECT_EQ(sa.chosen, sb.chosen);
  EXPECT_NE(sa.chosen, 0u);
  EXPECT_EQ(plan_of(*b).points_per_sample, plan_of(*a).points_per_sample);
}

TEST(AutoEstimator, AVectorIntegrandOffABoxIsRefusedNamingTheField) {
  const json spec = {{"kind", "integrate"},
                     {"integrand", {{"expressions", {"x0", "x0*x1"}}}},
                     {"domain", {{"type", "disk"}}},
                     {"estimator", {{"type", "auto"}}},
                     {"stop", {{"max_samples", 100}}}};
  try {
    compile_job(spec, JobLimits{});
    FAIL() << "accepted";
  } catch (const SpecError& e) {
    EXPECT_EQ(e.pointer(), "/estimator/type");
    EXPECT_NE(std::string(e.what()).find("interval or box domain"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace tally
