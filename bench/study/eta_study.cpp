// How to read a job's ETA: one job with an error target, its progress after every
// pass (prediction.samples_remaining / seconds_remaining) and its final cost curve,
// beside what the run then actually took.
#include <fmt/format.h>

#include <fstream>

#include "bench/study/study_support.hpp"
#include "common/engine/pass_loop.hpp"
#include "common/protocol/job_kinds.hpp"
#include "common/protocol/status_json.hpp"

namespace tally::study {

void run_eta_study(const Options& o) {
  const GenzParams p{GenzFamily::gaussian, {1.5, 2.5, 1.0, 2.0}, {0.35, 0.6, 0.5, 0.4}};
  const json spec = genz_spec(p, {{"type", "uniform"}}, {{"rel_error", 1e-3}, {"confidence", 0.95}}, 3);
  auto job = compile_job(spec, JobLimits{});
  JobRunner runner(job->kernel(), job->stop_rule(), JobCaps{});
  json passes = json::array();
  LocalRunOptions lo;
  lo.threads = o.threads;
  lo.on_pass = [&](const JobRunner& r) { passes.push_back(progress_json(r)); };
  run_local(runner, lo);
  const json result = result_json(runner, *job);
  Csv csv(o.out / "eta.csv", {"pass", "samples", "compute_seconds", "rel_error", "predicted_samples_needed",
                              "predicted_seconds_remaining", "final_samples", "final_seconds"});
  for (size_t i = 0; i < passes.size(); ++i) {
    const json& pj = passes[i];
    const json pred = pj["prediction"];
    csv.row({i + 1, pj["samples"], pj["compute_seconds"], pj["error"]["rel"],
             pred.is_null() ? json(nullptr) : pred["samples_needed"],
             pred.is_null() ? json(nullptr) : pred["seconds_remaining"], runner.state().samples,
             runner.state().compute_seconds});
  }
  std::ofstream(o.out / "eta_example.json") << json{{"spec", spec},
                                                    {"progress_after_first_pass", passes.front()},
                                                    {"cost_curve", result["cost_curve"]},
                                                    {"final", {{"samples", runner.state().samples},
                                                               {"compute_seconds", runner.state().compute_seconds},
                                                               {"stop_reason", result["stop_reason"]}}}}
                                                   .dump(2);
}

}  // namespace tally::study
