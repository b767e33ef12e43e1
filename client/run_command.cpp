#include "client/run_command.hpp"

#include <sys/resource.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fmt/format.h>
#include <fstream>
#include <iostream>
#include <sstream>
#include <thread>

#include "client/exit_codes.hpp"
#include "client/image_format.hpp"
#include "client/json_errors.hpp"
#include "common/image/image_io.hpp"
#include "common/engine/pass_loop.hpp"
#include "common/protocol/job_kinds.hpp"
#include "common/spec/spec_reader.hpp"
#include "common/protocol/status_json.hpp"
#include "server/host/memory_budget.hpp"

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
  std::string asset_dir;  // "" = the spec file's directory
};

// Writes the job's image to `path` in `format`; false (with the reason on stderr) on failure.
bool write_image(const JobDefinition& job, const JobRunner& runner, const std::string& path, ImageFormat format) {
  const ImageSource* source = job.image();
  if (!source) {
    fmt::print(stderr, "tally run: --image: this job makes no image (its query is not \"type\": \"image\")\n");
    return false;
  }
  const nlohmann::json meta = {{"samples", runner.state().samples}, {"passes", runner.state().passes}};
  if (format == ImageFormat::exr) {
    // Streamed from the state a strip of rows at a time: no copy of a 4K image.
    try {
      write_exr_file(*source, runner.state(), meta, path);
    } catch (const std::exception& e) {
      fmt::print(stderr, "tally run: cannot write {}: {}\n", path, e.what());
      return false;
    }
    std::error_code ec;
    const auto size = std::filesystem::file_size(path, ec);
    fmt::print(stderr, "wrote {} ({} bytes)\n", path, ec ? 0 : size);
    return true;
  }
  const ImageSnapshot snap = source->snapshot(runner.state());
  std::string bytes;
  try {
    bytes = encode_png(snap);
  } catch (const std::exception& e) {
    fmt::print(stderr, "tally run: cannot encode {}: {}\n", path, e.what());
    return false;
  }
  std::ofstream out(path, std::ios::binary);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  out.close();
  if (!out) {
    fmt::print(stderr, "tally run: cannot write {}: {}\n", path, std::strerror(errno));
    return false;
  }
  fmt::print(stderr, "wrote {} ({} bytes)\n", path, bytes.size());
  return true;
}

int run(const RunOptions& o) {
  const auto format = o.image_out.empty() ? std::optional<ImageFormat>() : image_format_of(o.image_out);
  if (!o.image_out.empty() && !format) {
    fmt::print(stderr, "tally run: {}\n", unknown_image_format_message(o.image_out));
    return exit_code::usage;
  }
  std::string text;
  if (o.path == "-") {
    std::stringstream ss;
    ss << std::cin.rdbuf();
    text = ss.str();
  } else {
    std::ifstream in(o.path, std::ios::binary);
    if (!in) {
      fmt::print(stderr, "tally run: cannot read {}: {}\n", o.path, std::strerror(errno));
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
    fmt::print(stderr, "tally run: {} is not valid JSON: {}\n", o.path == "-" ? "the spec on stdin" : o.path,
               json_parse_error_text(e));
    return exit_code::usage;
  }
  std::unique_ptr<JobDefinition> job;
  try {
    JobLimits limits;
    // One job in this process: its state may take half the machine's memory, as
    // tally-server's default (server/host/memory_budget.hpp).
    if (const uint64_t m = default_memory_budget()) limits.max_state_bytes = m;
    if (!o.asset_dir.empty()) {
      limits.asset_dir = o.asset_dir;
    } else {
      const std::filesystem::path dir = o.path == "-" ? std::filesystem::path(".") : std::filesystem::path(o.path).parent_path();
      limits.asset_dir = dir.empty() ? std::string(".") : dir.string();
    }
    job = compile_job(spec, limits);
  } catch (const SpecError& e) {
    fmt::print(stderr, "tally run: invalid job: {} (at \"{}\")\n", e.detail(), e.pointer());
    return exit_code::usage;
  }
  // The image module loads beside the render, not after it (joined when this function
  // returns; write_image waits for it through the module's own once). Not beside the
  // compile: a dlopen holds the loader's lock for its whole ~0.25 s, and the compile's
  // Embree device dlopens TBB's libraries, so it would wait for the module instead.
  std::jthread module_loader;
  if (format) module_loader = std::jthread([] { preload_image_module(); });
  JobRunner runner(job->kernel(), job->stop_rule(), JobCaps{});
  LocalRunOptions lo;
  lo.threads = o.threads > 0 ? o.threads : available_cpus();
  lo.cancel = &g_interrupted;
  if (o.progress) {
    lo.on_pass = [&](const JobRunner& r) {
      // Channel 0, or the headline of a kernel without tallies (an image's sums).
      const Estimate e = r.state().channels.empty() ? r.headline() : r.estimate(0);
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
      // What a frame's size costs: the process's peak resident memory so far (the image,
      // if asked for, is written after this line and streams a strip at a time).
      rusage ru{};
      if (getrusage(RUSAGE_SELF, &ru) == 0) fmt::print("peak memory {:.1f} MB\n", static_cast<double>(ru.ru_maxrss) / 1024.0);
    }
  }
  if (format && runner.stop_reason() != StopReason::failed && !write_image(*job, runner, o.image_out, *format)) {
    return exit_code::usage;
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
  cmd->add_option("--asset-dir", opts->asset_dir,
                  "Directory the scene's file names are relative to (default: the spec file's directory)");
  cmd->add_option("--image", opts->image_out,
                  "Write the job's image: out.exr (float RGB, standard errors, samples per pixel) or out.png "
                  "(8-bit preview); the format is the extension's");
  cmd->callback([opts, &exit_code] { exit_code = run(*opts); });
}

}  // namespace tally
