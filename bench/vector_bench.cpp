// Many integrands in one job (issue 31): a parameterized expression with thousands of
// values as one vector job, against a loop of single jobs doing the same integrals.
// Prints, from one run: evaluations per second of each (ratio vector / loop, interleaved
// rounds), job-state bytes per component, and peak RSS per component from two component
// counts run in child processes.
//
//   build/bench/vector_bench [components=10000] [single_jobs=200] [rounds=3]
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "common/engine/job_runner.hpp"
#include "common/engine/pass_loop.hpp"
#include "common/protocol/job_kinds.hpp"

namespace {

using nlohmann::json;
using tally::JobLimits;

constexpr int kDims = 4;
constexpr int kPoints = 1021;   // lattice points a sample (prime)
constexpr int kSamples = 16;    // random shifts

std::vector<double> values(size_t m) {
  std::vector<double> a(m);
  for (size_t i = 0; i < m; ++i) a[i] = 0.1 + 2.0 * static_cast<double>(i) / static_cast<double>(m);
  return a;
}

json spec(const json& integrand) {
  return {{"kind", "integrate"},
          {"seed", 3},
          {"integrand", integrand},
          {"domain", {{"type", "box"}, {"lower", std::vector<double>(kDims, 0.0)}, {"upper", std::vector<double>(kDims, 1.0)}}},
          {"estimator", {{"type", "lattice"}, {"points", kPoints}}},
          {"stop", {{"max_samples", kSamples}}}};
}

const char* kTemplate = "exp(-a*(x0+x1+x2+x3))";

struct Run {
  double seconds = 0;
  uint64_t evaluations = 0;
  size_t state_bytes = 0;
};

Run run_job(const json& s) {
  const auto t0 = std::chrono::steady_clock::now();
  auto job = tally::compile_job(s, JobLimits{});
  tally::JobRunner runner(job->kernel(), job->stop_rule(), tally::JobCaps{});
  tally::run_local(runner, 1);
  Run r;
  r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  r.evaluations = runner.state().samples * kPoints * job->kernel()->channel_count();
  r.state_bytes = runner.state().channels.size() * sizeof(tally::Tally);
  return r;
}

Run vector_job(size_t m) { return run_job(spec({{"expression", kTemplate}, {"parameters", {{"a", values(m)}}}})); }

Run single_jobs(size_t count, size_t m) {
  const std::vector<double> a = values(m);
  Run total;
  for (size_t i = 0; i < count; ++i) {
    char lit[64];
    std::snprintf(lit, sizeof lit, "(%.17g)", a[i * (m / count)]);
    const std::string text = std::string("exp(-") + lit + "*(x0+x1+x2+x3))";  // kTemplate bound
    const Run r = run_job(spec({{"expression", text}}));
    total.seconds += r.seconds;
    total.evaluations += r.evaluations;
  }
  return total;
}

long peak_rss_kb() {
  std::ifstream f("/proc/self/status");
  std::string line;
  while (std::getline(f, line)) {
    if (line.rfind("VmHWM:", 0) == 0) return std::strtol(line.c_str() + 6, nullptr, 10);
  }
  return -1;
}

// Peak RSS (kB) of a fresh child process that runs the vector job of m components.
long child_peak_kb(size_t m) {
  int fd[2];
  if (pipe(fd) != 0) return -1;
  const pid_t pid = fork();
  if (pid == 0) {
    close(fd[0]);
    vector_job(m);
    const long kb = peak_rss_kb();
    if (write(fd[1], &kb, sizeof kb) != sizeof kb) _exit(1);
    _exit(0);
  }
  close(fd[1]);
  long kb = -1;
  if (read(fd[0], &kb, sizeof kb) != sizeof kb) kb = -1;
  close(fd[0]);
  int status = 0;
  waitpid(pid, &status, 0);
  return kb;
}

}  // namespace

int main(int argc, char** argv) {
  const size_t m = argc > 1 ? std::strtoull(argv[1], nullptr, 10) : 10000;
  const size_t singles = argc > 2 ? std::strtoull(argv[2], nullptr, 10) : 200;
  const int rounds = argc > 3 ? std::atoi(argv[3]) : 3;
  // Peak RSS first, in children forked while this process is still small.
  const size_t small = m / 10;
  const long lo = child_peak_kb(small), hi = child_peak_kb(m);
  std::printf("vector job: %zu components of %s on [0,1]^%d, lattice %d points x %d shifts, 1 thread\n", m,
              kTemplate, kDims, kPoints, kSamples);
  std::printf("%-6s %14s %14s %8s\n", "round", "vector Meval/s", "loop Meval/s", "ratio");
  std::vector<double> ratios;
  Run last;
  for (int i = 0; i < rounds; ++i) {  // interleaved: the machine's noise hits both alike
    last = vector_job(m);
    const Run loop = single_jobs(singles, m);
    const double v = static_cast<double>(last.evaluations) / last.seconds / 1e6;
    const double l = static_cast<double>(loop.evaluations) / loop.seconds / 1e6;
    ratios.push_back(v / l);
    std::printf("%-6d %14.1f %14.1f %8.2f\n", i + 1, v, l, v / l);
  }
  std::sort(ratios.begin(), ratios.end());
  std::printf("median ratio vector / loop of single jobs (evaluations per second): %.2f\n", ratios[ratios.size() / 2]);
  std::printf("job state: %.1f bytes per component (one tally each, no covariance)\n",
              static_cast<double>(last.state_bytes) / static_cast<double>(m));
  std::printf("peak RSS: %ld kB at %zu components, %ld kB at %zu: %.0f bytes per component\n", lo, small, hi, m,
              1024.0 * static_cast<double>(hi - lo) / static_cast<double>(m - small));
  return 0;
}
