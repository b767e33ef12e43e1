#include "server/api/pilot.hpp"

#include <chrono>
#include <cmath>
#include <condition_variable>
#include <limits>
#include <mutex>
#include <stop_token>
#include <thread>

#include "common/engine/local_executor.hpp"
#include "common/stats/confidence.hpp"

namespace tally {

using nlohmann::json;

namespace {
json finite_or_null(double v) { return std::isfinite(v) ? json(v) : json(nullptr); }
}  // namespace

json run_pilot(const JobDefinition& job, const PilotOptions& options) {
  using clock = std::chrono::steady_clock;
  const StopRule rule = job.stop_rule();
  JobRunner runner(job.kernel(), rule, options.caps);
  std::atomic<bool> cancel{false};
  const auto t0 = clock::now();
  const auto soft = t0 + std::chrono::duration_cast<clock::duration>(std::chrono::duration<double>(options.seconds));
  const auto hard =
      t0 + std::chrono::duration_cast<clock::duration>(std::chrono::duration<double>(4 * options.seconds));
  std::mutex mu;
  std::condition_variable_any cv;
  std::jthread watchdog([&](std::stop_token st) {
    std::unique_lock lock(mu);
    cv.wait_until(lock, st, hard, [] { return false; });
    if (!st.stop_requested()) cancel = true;
  });
  bool cut = false;
  std::vector<BlockResult> results;
  while (!runner.finished() && clock::now() < soft) {
    const std::vector<Block> blocks = runner.plan_pass();
    if (blocks.empty()) break;
    const auto p0 = clock::now();
    if (!run_blocks(runner.kernel(), blocks, options.threads, results, &cancel, runner.pass_input())) {
      cut = true;
      break;
    }
    runner.commit_pass(std::move(results), std::chrono::duration<double>(clock::now() - p0).count());
    results = {};
  }
  watchdog.request_stop();
  const double elapsed = std::chrono::duration<double>(clock::now() - t0).count();

  const JobState& s = runner.state();
  const ErrorSummary err = runner.error();
  const double rate = runner.samples_per_second();
  json pilot = {{"passes", s.passes},
                {"samples", s.samples},
                {"seconds", elapsed},
                {"samples_per_second", rate},
                {"mean", finite_or_null(err.mean)},
                {"sigma", finite_or_null(err.sigma)},
                {"abs_error", finite_or_null(err.abs_error)},
                {"rel_error", finite_or_null(err.rel_error)},
                {"heavy_tail", runner.heavy_tail()},
                {"warnings", runner.warnings()}};
  if (cut && s.passes == 0) pilot["note"] = "the pilot could not finish one pass in time; no prediction";

  json pred = nullptr;
  // The job will run on `parallelism` workers; the pilot ran on `threads`.
  const double job_rate = rate * std::max(1u, options.parallelism) / std::max(1u, options.threads);
  pilot["job_samples_per_second"] = job_rate;
  if (s.passes > 0 && rate > 0) {
    const double inf = std::numeric_limits<double>::infinity();
    double best_s = inf;
    std::string fires;
    json by_rule = json::object();
    auto consider = [&](const char* name, double samples, double seconds) {
      by_rule[name] = {{"samples", finite_or_null(samples)}, {"seconds", finite_or_null(seconds)}};
      if (seconds < best_s) {
        best_s = seconds;
        fires = name;
      }
    };
    if (rule.has_error_target() && std::isfinite(err.sigma)) {
      double need = inf;
      if (rule.abs_error > 0) need = std::min(need, samples_for_half_width(err.sigma, rule.abs_error, rule.confidence));
      if (rule.rel_error > 0 && err.mean != 0.0) {
        need = std::min(need, samples_for_half_width(err.sigma, rule.rel_error * std::fabs(err.mean), rule.confidence));
      }
      need = std::max(need, static_cast<double>(rule.min_samples));
      consider("error_target", need, need / job_rate);
    }
    if (rule.max_samples > 0) {
      consider("max_samples", static_cast<double>(rule.max_samples), static_cast<double>(rule.max_samples) / job_rate);
    }
    if (rule.time_budget_s > 0) consider("time_budget", rule.time_budget_s * job_rate, rule.time_budget_s);
    const double cap_s = std::min(options.caps.max_seconds, static_cast<double>(options.caps.max_samples) / job_rate);
    consider("job_cap", cap_s * job_rate, cap_s);
    pred = {{"stops_by", fires},
            {"samples", finite_or_null(best_s * job_rate)},
            {"seconds", finite_or_null(best_s)},
            {"by_rule", by_rule},
            {"reliable", !runner.heavy_tail()}};
    json curve = json::array();
    for (const CostPoint& c : runner.cost_curve({1e-2, 1e-3, 1e-4})) {
      curve.push_back({{"rel_error", c.rel_error},
                       {"samples", finite_or_null(c.samples)},
                       {"seconds", finite_or_null(c.samples / job_rate)}});
    }
    pred["cost_curve"] = curve;
  }
  return {{"pilot", pilot}, {"prediction", pred}};
}

}  // namespace tally
