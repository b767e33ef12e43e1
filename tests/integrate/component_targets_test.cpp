// Per-component error targets of a vector job (issue 31): "stop.component_targets" gives
// each component its own abs_error / rel_error (null: the job-wide one). The job stops
// at its error target when every component meets its own; the summary counts and lists
// the ones that do not; the targets survive the stored rule and a checkpoint resume.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <string>
#include <utility>
#include <variant>
#include <vector>

#include "common/engine/component_targets.hpp"
#include "common/integrate/integration_job.hpp"
#include "common/protocol/integration_json.hpp"
#include "common/spec/stop_rule_json.hpp"
#include "integrate/run_support.hpp"

namespace tally {
namespace {

using nlohmann::json;
using testing::run_spec;

// x^1, x^2, x^3 over [0, 1]: exact 1/2, 1/3, 1/4.
json powers_job(json estimator, json stop) {
  return {{"kind", "integrate"},
          {"seed", 7},
          {"integrand", {{"expressions", {"x0", "x0^2", "x0^3"}}}},
          {"domain", {{"type", "box"}, {"lower", {0.0}}, {"upper", {1.0}}}},
          {"estimator", std::move(estimator)},
          {"stop", std::move(stop)}};
}

IntegrationResult result_of(const JobDefinition& job, const JobRunner& runner) {
  return dynamic_cast<const IntegrationJob&>(job).result(runner);
}

// compile_job's SpecError for `spec` as "pointer: detail", or "<accepted>".
std::string spec_error(const json& spec) {
  try {
    compile_job(spec, JobLimits{});
  } catch (const SpecError& e) {
    return e.pointer() + ": " + e.detail();
  }
  return "<accepted>";
}

TEST(ComponentTargets, BadTargetsAreRefusedNamingTheField) {
  const json qmc = {{"type", "qmc"}, {"points", 16}};
  auto with = [&](json targets, json stop = {{"max_samples", 64}, {"rel_error", 1e-3}}) {
    stop["component_targets"] = std::move(targets);
    return powers_job(qmc, stop);
  };
  EXPECT_EQ(spec_error(with({{"rel_error", {1e-3, 1e-3}}})),
            "/stop/component_targets/rel_error: has 2 entries; the integrand has 3 components");
  EXPECT_EQ(spec_error(with({{"abs_error", {1e-3, -1.0, nullptr}}})),
            "/stop/component_targets/abs_error/1: must be in [1e-300, 1e+300], got -1");
  EXPECT_EQ(spec_error(with({{"rel_error", {1e-3, 0.0, nullptr}}})),
            "/stop/component_targets/rel_error/1: must be in [1e-12, 1000], got 0");
  EXPECT_EQ(spec_error(with({{"abs_error", {std::numeric_limits<double>::quiet_NaN(), 1e-3, 1e-3}}})),
            "/stop/component_targets/abs_error/0: must be a finite number");
  EXPECT_EQ(spec_error(with({{"rel_error", {1e-3, 1e-3, "1e-3"}}})),
            "/stop/component_targets/rel_error/2: must be a number, got a string");
  EXPECT_EQ(spec_error(with({{"rel_error", 1e-3}})),
            "/stop/component_targets/rel_error: must be an array, got a number");
  EXPECT_EQ(spec_error(with(json::object())),
            "/stop/component_targets: needs abs_error or rel_error (one entry per component)");
  EXPECT_EQ(spec_error(with({{"rel_error", {1e-3, 1e-3, 1e-3}}, {"relerror", 1}})),
            "/stop/component_targets/relerror: unknown field");
  EXPECT_EQ(spec_error(with({{"abs_error", {1e-3, 1e-3, 1e-3}}, {"rel_error", {1e-3, 1e-3}}})),
            "/stop/component_targets/rel_error: has 2 entries; abs_error has 3");
  EXPECT_EQ(spec_error(with({{"rel_error", std::vector<double>(16385, 1e-3)}})),
            "/stop/component_targets/rel_error: must have 1 to 16384 entries (one per component), got 16385");
  EXPECT_EQ(spec_error(with(json::array())), "/stop/component_targets: must be an object, got an array");
  // A null entry needs a job-wide target to fall back on.
  EXPECT_EQ(spec_error(with({{"rel_error", {1e-3, nullptr, 1e-3}}}, {{"max_samples", 64}})),
            "/stop/component_targets: component 1 has no error target: its entries are null and the rule has no "
            "job-wide abs_error or rel_error");
  // A scalar integrand has one target; cubature runs one rule for all components.
  json scalar = with({{"rel_error", {1e-3}}});
  scalar["integrand"] = {{"expression", "x0"}};
  EXPECT_EQ(spec_error(scalar), "/stop/component_targets: needs a vector integrand (expressions, parameters or "
                                "families); a scalar one has abs_error and rel_error");
  json cub = with({{"rel_error", {1e-3, 1e-3, 1e-3}}});
  cub["estimator"] = {{"type", "cubature"}};
  EXPECT_EQ(spec_error(cub), "/stop/component_targets: cubature runs one rule with one abs_error and rel_error "
                             "for every component; per-component targets need a sampling estimator");
  // The same list, well formed, is accepted; a target of its own replaces a missing job-wide one.
  EXPECT_EQ(spec_error(with({{"rel_error", {1e-3, nullptr, 1e-3}}, {"abs_error", {nullptr, 1e-3, nullptr}}},
                            {{"max_samples", 64}})),
            "<accepted>");
}

struct Targets {
  std::vector<double> abs, rel;  // per component, 0: the job-wide one
  double job_abs = 0.0, job_rel = 0.0;
  // Component c meets its target, read from the result as a client would.
  bool met(size_t c, const ComponentEstimate& e) const {
    const double half = 0.5 * (e.ci_hi - e.ci_lo);
    const double a = abs[c] > 0 ? abs[c] : job_abs, r = rel[c] > 0 ? rel[c] : job_rel;
    return (a > 0 && half <= a) || (r > 0 && half <= r * std::fabs(e.mean));
  }
  json stop() const {
    auto list = [](const std::vector<double>& v) {
      json a = json::array();
      for (double x : v) a.push_back(x > 0 ? json(x) : json(nullptr));
      return a;
    };
    json s = {{"component_targets", {{"abs_error", list(abs)}, {"rel_error", list(rel)}}}};
    if (job_abs > 0) s["abs_error"] = job_abs;
    if (job_rel > 0) s["rel_error"] = job_rel;
    return s;
  }
};

struct TargetRun {
  uint64_t samples = 0;
  std::vector<bool> met_at_stop;
};

// Runs `job` and checks after every pass that the job has stopped exactly when every
// component meets its own target (read from the result, independently of the engine).
TargetRun run_checking_every_pass(const json& spec, const Targets& t) {
  const auto def = compile_job(spec, JobLimits{});
  JobRunner runner(def->kernel(), def->stop_rule(), JobCaps{});
  LocalRunOptions o;
  o.threads = 2;
  o.on_pass = [&](const JobRunner& jr) {
    const IntegrationResult r = result_of(*def, jr);
    bool all = jr.state().samples >= jr.rule().min_samples;
    for (size_t c = 0; c < r.components.size(); ++c) all = all && t.met(c, r.components[c]);
    EXPECT_EQ(all, jr.finished()) << "pass " << jr.state().passes << ", " << jr.state().samples << " samples";
  };
  run_local(runner, o);
  EXPECT_EQ(runner.stop_reason(), StopReason::error_target) << spec;
  const IntegrationResult r = result_of(*def, runner);
  TargetRun out;
  out.samples = runner.state().samples;
  for (size_t c = 0; c < r.components.size(); ++c) out.met_at_stop.push_back(t.met(c, r.components[c]));
  EXPECT_EQ(r.components_summary->met, r.components.size());
  EXPECT_TRUE(r.components_summary->unmet.empty());
  return out;
}

// Three components with very different targets (an absolute one, a relative one, and the
// job-wide one through a null entry) on the VEGAS kernel (uniform) and a sweep kernel
// (qmc). The job stops at the first pass where each meets its own, and tightening one
// component's target makes it run longer. Fixed seed: deterministic.
TEST(ComponentTargets, EachComponentStopsAtItsOwnTarget) {
  const std::vector<std::pair<json, Targets>> cases = {
      // Uniform: rel sd of x, x^2, x^3 is 0.58, 0.89, 1.13: ~13k, ~85k, ~12k samples.
      // Component 1's own relative target is out of reach, so its absolute one decides.
      {{{"type", "uniform"}}, Targets{{0, 2e-3, 0}, {1e-2, 1e-9, 0}, 0.0, 2e-2}},
      {{{"type", "qmc"}, {"points", 16}}, Targets{{0, 2e-5, 0}, {1e-4, 1e-9, 0}, 0.0, 3e-4}},
  };
  for (const auto& [est, t] : cases) {
    SCOPED_TRACE(est.dump());
    const TargetRun base = run_checking_every_pass(powers_job(est, t.stop()), t);
    EXPECT_EQ(base.met_at_stop, std::vector<bool>(3, true));
    // Component 0 four times tighter: it now decides, later.
    Targets tight = t;
    tight.rel[0] /= 4;
    const TargetRun longer = run_checking_every_pass(powers_job(est, tight.stop()), tight);
    EXPECT_GT(longer.samples, base.samples);
    // Without component targets the job-wide rule alone stops it earlier still.
    json loose = t.stop();
    loose.erase("component_targets");
    const auto plain = run_spec(powers_job(est, loose), 2);
    EXPECT_EQ(plain->stop_reason(), StopReason::error_target);
    EXPECT_LT(plain->state().samples, base.samples);
  }
}

// A sweep job keeps pair channels for the covariance (m <= 64) beside its components; the
// targets read the components only, so a job with no job-wide target (the pairs have none)
// still stops at its components' own targets.
TEST(ComponentTargets, PairChannelsAreNotComponents) {
  const Targets t{{0, 2e-5, 0}, {1e-4, 0, 3e-4}, 0.0, 0.0};
  json stop = t.stop();
  stop["max_samples"] = 1 << 20;
  const auto r = run_spec(powers_job({{"type", "qmc"}, {"points", 16}}, stop), 2);
  EXPECT_EQ(r->state().channels.size(), 3u + 3u);  // 3 components + 3 pairs
  EXPECT_EQ(r->stop_reason(), StopReason::error_target);
  EXPECT_LT(r->state().samples, 1u << 20);
}

// max_samples stops the job first: the summary counts the components that miss their
// target and lists the first 100 of them by index. 250 components x^p; the even ones have
// a reachable target of their own, the odd ones fall back on an unreachable job-wide one.
TEST(ComponentTargets, MaxSamplesFirstListsTheUnmetComponents) {
  std::vector<double> p;
  json rel = json::array();
  for (int i = 0; i < 250; ++i) {
    p.push_back(0.5 + 0.01 * i);
    rel.push_back(i % 2 == 0 ? json(0.5) : json(nullptr));
  }
  json spec = powers_job({{"type", "qmc"}, {"points", 16}},
                         {{"max_samples", 32}, {"rel_error", 1e-12}, {"component_targets", {{"rel_error", rel}}}});
  spec["integrand"] = {{"expression", "x0^p"}, {"parameters", {{"p", p}}}};
  const auto r = run_spec(spec, 2);
  EXPECT_EQ(r->stop_reason(), StopReason::max_samples);
  const IntegrationResult res = result_of(*r.job, *r.runner);
  ASSERT_TRUE(res.components_summary);
  const ComponentsSummary& s = *res.components_summary;
  ASSERT_TRUE(s.met);
  EXPECT_EQ(*s.met, 125u);
  std::vector<uint64_t> first;
  for (uint64_t i = 1; first.size() < 100; i += 2) first.push_back(i);
  EXPECT_EQ(s.unmet, first);
  EXPECT_EQ(s.worst % 2, 1u);  // an odd one: furthest from its (job-wide) target
  const json j = components_summary_json(s);
  EXPECT_EQ(j["met"], 125);
  EXPECT_EQ(j["unmet"]["count"], 125);
  EXPECT_EQ(j["unmet"]["first"], json(first));
}

// The server stores the rule (stop_rule_to_json) and restores a job from its checkpoint
// with the stored rule (parse_stored_stop_rule): the targets come back the same, and the
// resumed job stops where the uninterrupted one did, with the same bits. Only component
// targets are set (no job-wide one): a rule that lost them would run to max_samples.
TEST(ComponentTargets, TheStoredRuleKeepsTheTargetsAndResumesBitIdentically) {
  const Targets t{{0, 2e-3, 0}, {1e-2, 0, 2e-2}, 0.0, 0.0};
  json stop = t.stop();
  stop["max_samples"] = 4000000;
  const json spec = powers_job({{"type", "uniform"}}, stop);
  const auto whole = run_spec(spec, 2);
  ASSERT_EQ(whole->stop_reason(), StopReason::error_target);
  ASSERT_LT(whole->state().samples, 1000000u);

  const testing::Interrupted cut = testing::run_until_pass(spec, 2);
  ASSERT_FALSE(cut.checkpoint.empty());
  const StopRule compiled = cut.run.job->stop_rule();
  const json stored_json = json::parse(stop_rule_to_json(compiled).dump());  // as the store keeps it
  SpecReader rd(stored_json, "/stop");
  const StopRule stored = parse_stored_stop_rule(rd, JobLimits{});
  ASSERT_TRUE(stored.component_targets);
  EXPECT_EQ(*stored.component_targets, *compiled.component_targets);
  EXPECT_EQ(stored.component_targets->abs_error, (std::vector<double>{0, 2e-3, 0}));
  EXPECT_EQ(stored.component_targets->rel_error, (std::vector<double>{1e-2, 0, 2e-2}));

  const auto def = compile_job(spec, JobLimits{});
  JobRunner resumed(def->kernel(), stored, JobCaps{}, decode_checkpoint(cut.checkpoint));
  run_local(resumed, 1);
  EXPECT_EQ(resumed.stop_reason(), StopReason::error_target);
  testing::expect_same_state(resumed.state(), whole->state());
}

// The runner forecasts the error target from the component furthest from its own target:
// n * ratio^2 samples (half-widths fall as 1/sqrt(n)), which sizes the next pass, instead
// of doubling the passes blindly.
TEST(ComponentTargets, PredictionIsTheFurthestComponentsNeed) {
  const Targets t{{0, 2e-5, 0}, {1e-4, 1e-9, 0}, 0.0, 3e-4};
  const json spec = powers_job({{"type", "qmc"}, {"points", 16}}, t.stop());
  const testing::Interrupted cut = testing::run_until_pass(spec, 2);
  ASSERT_FALSE(cut.checkpoint.empty());
  const JobRunner& jr = *cut.run.runner;
  const IntegrationResult r = result_of(*cut.run.job, jr);
  double worst = 0.0;
  for (size_t c = 0; c < r.components.size(); ++c) {
    const ComponentEstimate& e = r.components[c];
    const double half = 0.5 * (e.ci_hi - e.ci_lo);
    double ratio = std::numeric_limits<double>::infinity();
    if (t.abs[c] > 0) ratio = std::min(ratio, half / t.abs[c]);
    const double rel = t.rel[c] > 0 ? t.rel[c] : t.job_rel;
    ratio = std::min(ratio, half / std::fabs(e.mean) / rel);
    worst = std::max(worst, ratio);
  }
  ASSERT_GT(worst, 1.0);  // not met yet
  const auto p = jr.prediction();
  ASSERT_TRUE(p);
  const double n = static_cast<double>(jr.state().samples);
  EXPECT_NEAR(p->samples_needed, n * worst * worst, 1e-9 * n * worst * worst);
  EXPECT_NEAR(p->samples_remaining, n * worst * worst - n, 1e-9 * n * worst * worst);
}

// The stop rule of a job with these targets and max_samples 1000, as extend keeps it.
StopRule kept_rule(const Targets& t) {
  json stop = t.stop();
  stop["max_samples"] = 1000;
  return compile_job(powers_job({{"type", "uniform"}}, stop), JobLimits{})->stop_rule();
}

// Reads an extend body with `keep` kept, as the extend route does: the rule, or the 422's text.
std::variant<StopRule, std::string> extend_with(const StopRule& keep, const json& body) {
  SpecReader reader(body, "");
  try {
    return parse_stop_rule(reader, JobLimits{}, &keep);
  } catch (const SpecError& e) {
    return std::string(e.what());
  }
}

// The extend route reads its body with the job's rule kept: the targets stay, and the body
// may not replace them.
TEST(ComponentTargets, ExtendKeepsTheTargets) {
  const StopRule keep = kept_rule({{0, 2e-3, 0}, {1e-2, 0, 2e-2}, 0.0, 0.0});
  const auto extended = extend_with(keep, {{"max_samples", 5000}});
  ASSERT_TRUE(std::holds_alternative<StopRule>(extended)) << std::get<std::string>(extended);
  EXPECT_EQ(std::get<StopRule>(extended).max_samples, 5000u);
  ASSERT_TRUE(std::get<StopRule>(extended).component_targets);
  EXPECT_EQ(*std::get<StopRule>(extended).component_targets, *keep.component_targets);
  const auto replaced =
      extend_with(keep, {{"max_samples", 5000}, {"component_targets", {{"rel_error", {1, 1, 1}}}}});
  ASSERT_TRUE(std::holds_alternative<std::string>(replaced)) << "accepted";
  EXPECT_EQ(std::get<std::string>(replaced),
            "/component_targets: a job keeps its component targets; extend sets the job-wide ones");
}

// A component whose entries are null falls back on the job-wide target: an extend whose
// rule drops it is refused naming the job-wide field to set, and accepted with it.
TEST(ComponentTargets, ExtendWithoutTheJobWideTargetANullEntryNeedsIsRefused) {
  // Component 2 relies on the job-wide rel_error.
  const StopRule keep = kept_rule({{0, 2e-3, 0}, {1e-2, 0, 0}, 0.0, 5e-2});
  const auto refused = extend_with(keep, {{"max_samples", 5000}});
  ASSERT_TRUE(std::holds_alternative<std::string>(refused)) << "accepted";
  EXPECT_EQ(std::get<std::string>(refused),
            "/rel_error: component 2 has no error target: its entries are null and the rule has no job-wide "
            "abs_error or rel_error (extend keeps the job's component targets and replaces its job-wide ones)");
  const auto extended = extend_with(keep, {{"max_samples", 5000}, {"rel_error", 2e-2}});
  ASSERT_TRUE(std::holds_alternative<StopRule>(extended)) << std::get<std::string>(extended);
  EXPECT_EQ(component_rel_target(std::get<StopRule>(extended), 0), 1e-2) << "its own entry";
  EXPECT_EQ(component_rel_target(std::get<StopRule>(extended), 2), 2e-2) << "the extend's job-wide rel_error";
}

}  // namespace
}  // namespace tally
