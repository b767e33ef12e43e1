#include "client/run_command.hpp"

#include <unistd.h>

#include <atomic>
#include <csignal>
#include <cstdio>
#include <fmt/format.h>
#include <fstream>
#include <iostream>
#include <sstream>

#include "client/exit_codes.hpp"
#include "common/engine/local_executor.hpp"
#include "common/jobs/job_factory.hpp"
#include "common/protocol/spec_reader.hpp"
#include "common/protocol/kind_json.hpp"
#include "common/protocol/status_json.hpp"

namespace tally {

namespace {

std::atomic<bool> g_interrupted{false};

extern "C" void on_sigint(int) { g_interrupted.store(true); }

struct RunOptions {
  std::string path;
  bool json = false;
  bool progress = false;
  unsigned threads = 0;
  std::string image_out;
};

int run(const RunOptions& o) {
  std::string text;
  if (o.path == "-") {
    std::stringstream ss;
    ss << std::cin.rdbuf();
    text = ss.str();
  } else {
    std::ifstream in(o.path, std::ios::binary);
    if (!in) {
      fmt::print(stderr, "tally run: cannot read {}\n", o.path);
      return exit_code::usage;
    }
    std::stringstream ss;
    ss << in.rdbuf();
    text = ss.str();
  }
  nlohmann::json spec;
  try {
    spec = nlohmann::json::parse(text);
  } catch (const nlohmann::json::parse_error& e) {
    fmt::print(stderr, "tally run: {} is not valid JSON: {}\n", o.path, e.what());
    return exit_code::usage;
  }
  std::unique_ptr<JobDefinition> job;
  try {
    job = compile_job(spec, JobLimits{});
  } catch (const SpecError& e) {
    fmt::print(stderr, "tally run: invalid job: {} (at \"{}\")\n", e.detail(), e.pointer());
    return exit_code::usage;
  }
  JobRunner runner(job->kernel(), job->stop_rule(), JobCaps{});
  LocalRunOptions lo;
  lo.threads = o.threads > 0 ? o.threads : available_cpus();
  lo.cancel = &g_interrupted;
  if (o.progress) {
    lo.on_pass = [&](const JobRunner& r) {
      const Estimate e = r.estimate(0);
      fmt::print(stderr, "pass {:>3}  n = {:<12} mean = {:.10g} ± {:.3g}  {:.3g} samples/s\n",
                 r.state().passes, r.state().samples, e.mean, e.std_error, r.samples_per_second());
    };
  }
  std::signal(SIGINT, on_sigint);
  run_local(runner, lo);
  std::signal(SIGINT, SIG_DFL);

  if (o.json) {
    nlohmann::json out = result_json(runner, *job);
    out["plan"] = plan_json(*job);
    std::cout << out.dump(2) << "\n";
  } else {
    const JobState& s = runner.state();
    if (runner.stop_reason() == StopReason::failed) {
      fmt::print("failed: {}\n", runner.error_message().value_or("unknown error"));
    } else {
      fmt::print("{}\n", job->summary_line(runner));
      fmt::print("samples {}  time {:.3f} s  ({:.3g} samples/s)  stopped by {}{}\n", s.samples,
                 s.compute_seconds, runner.samples_per_second(), stop_reason_name(runner.stop_reason()),
                 runner.rule().has_error_target()
                     ? (runner.target_met() ? " (error target met)" : " (error target NOT met)")
                     : "");
      for (const auto& w : runner.warnings()) fmt::print("warning: {}\n", w);
    }
  }
  switch (runner.stop_reason()) {
    case StopReason::failed:
    case StopReason::cancelled: return exit_code::job_failed;
    default: break;
  }
  if (runner.rule().has_error_target() && !runner.target_met()) return exit_code::target_not_met;
  return exit_code::ok;
}

}  // namespace

void add_run_command(CLI::App& app, int& exit_code) {
  auto opts = std::make_shared<RunOptions>();
  CLI::App* cmd = app.add_subcommand("run", "Run a job in-process with the embedded engine (no server)");
  cmd->add_option("job", opts->path, "Job spec (JSON file, or - for stdin)")->required();
  cmd->add_flag("--json", opts->json, "Print the full result as JSON");
  cmd->add_flag("--progress", opts->progress, "Print one line per pass on stderr");
  cmd->add_option("--threads", opts->threads, "Worker threads (default: the CPUs available)");
  cmd->callback([opts, &exit_code] { exit_code = run(*opts); });
}

}  // namespace tally
