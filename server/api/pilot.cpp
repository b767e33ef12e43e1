#include "server/api/pilot.hpp"

#include <chrono>
#include <cmath>
#include <condition_variable>
#include <limits>
#include <mutex>
#include <stop_token>
#include <thread>

#include "common/engine/forecast.hpp"
#include "common/engine/pass_loop.hpp"

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
  LocalRunOptions run;
  run.threads = options.threads;
  run.cancel = &cancel;
  run.keep_going = [&] { return clock::now() < soft; };
  const bool cut = !run_local(runner, run);
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
  // The real job would fail the same way (same seed, same first samples): say so.
  const bool failed = runner.stop_reason() == StopReason::failed;
  if (failed) pilot["error"] = runner.error_message().value_or("the pilot failed");

  json pred = nullptr;
  // The job will run on `parallelism` workers; the pilot ran on `threads`.
  const double job_rate = rate * std::max(1u, options.parallelism) / std::max(1u, options.threads);
  pilot["job_samples_per_second"] = job_rate;
  if (!failed && s.passes > 0 && rate > 0) {
    // The one forecast, for a job that starts from zero at the job's rate.
    const Forecast f = forecast(rule, options.caps, err, 0, 0.0, job_rate);
    double best_s = std::numeric_limits<double>::infinity();
    std::string fires;
    json by_rule = json::object();
    auto consider = [&](const char* name, const std::optional<RuleForecast>& rf) {
      if (!rf) return;
      by_rule[name] = {{"samples", finite_or_null(rf->samples)}, {"seconds", finite_or_null(rf->seconds)}};
      if (rf->seconds < best_s) {
        best_s = rf->seconds;
        fires = name;
      }
    };
    consider("error_target", f.error_target);
    consider("max_samples", f.max_samples);
    consider("time_budget", f.time_budget);
    consider("job_cap", f.job_cap);
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
