// The shared farm's two latencies (issue 32), in process: prints figures, not a test.
//  1. Preemption: --max-running low-priority image jobs hold every slot; a priority-5
//     job is submitted. Printed: how long until it runs, against the preempted job's
//     pass in flight at the submit (the goal: within one pass).
//  2. Result cache: an integration job that computes for ≥ 10 s, then the same spec
//     submitted again. Printed: the compute time and the cached submit's latency
//     (the goal: ≤ 10 ms).
// Usage: farm_bench [workers [samples]]   (default 2 workers; the slow job's max_samples,
// default 200 M: about 30 s on 2 idle cores)
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <cstdio>
#include <cstdlib>
#include <thread>

#include "common/protocol/job_kinds.hpp"
#include "server/jobs/job_manager.hpp"
#include "tests/support/frame_scene.hpp"

using nlohmann::json;
using namespace tally;
using Clock = std::chrono::steady_clock;

namespace {

double since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

template <class P>
bool wait_for(P pred, double seconds) {
  const auto t0 = Clock::now();
  while (since(t0) < seconds) {
    if (pred()) return true;
    std::this_thread::sleep_for(std::chrono::microseconds(500));
  }
  return pred();
}

// A long image job (tests/support/frame_scene.hpp) with its own seed.
json image_spec(int w, int h, uint64_t seed) {
  json spec = scenes::frame_spec(w, h, 100000000);
  spec["query"].erase("max_depth");  // the default path depth, as the figures in docs were measured
  spec["seed"] = seed;
  return spec;
}

// A job's completed passes and samples from a views read (cheap for a running job: its
// figures from its last pass boundary).
std::pair<uint64_t, uint64_t> progress(JobManager& m, const std::string& id) {
  const JobSnapshot s = m.snapshot(id);
  if (s.facts) return {s.facts->passes, s.facts->samples};
  if (s.runner) return {s.runner->state().passes, s.runner->state().samples};
  return {0, 0};
}

}  // namespace

int main(int argc, char** argv) {
  const unsigned workers = argc > 1 ? static_cast<unsigned>(std::atoi(argv[1])) : 2;
  // The server's default store (SQLite, in a directory of its own), as users run it.
  const std::filesystem::path dir =
      std::filesystem::temp_directory_path() / ("tally_farm_bench_" + std::to_string(::getpid()));
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  auto store = open_sqlite_store(dir.string());
  ManagerConfig mc;
  mc.workers = workers;
  mc.max_running = workers;
  mc.preempt_min_run_s = 0;
  JobManager m(mc, *store, compile_job);
  m.recover();

  // 1. Preemption latency. The pass in flight at the submit is the preempted job's first
  // pass whose samples exceed those it had at the submit; its length comes from the job's
  // own trace (compute time at each pass boundary). "Within one pass" means the urgent
  // job started no later than that pass ended, so latency <= pass in flight.
  std::vector<std::string> low;
  for (unsigned i = 0; i < workers; ++i) low.push_back(m.submit(image_spec(256, 256, i + 1), 0)->id());
  for (const auto& id : low) wait_for([&] { return progress(m, id).first >= 3; }, 60);
  std::vector<uint64_t> samples_at_submit;
  for (const auto& id : low) samples_at_submit.push_back(progress(m, id).second);
  const auto t0 = Clock::now();
  const std::string urgent = m.submit(image_spec(64, 64, 99), 5)->id();
  const double acknowledged = since(t0);
  const bool started = wait_for([&] { return m.snapshot(urgent).status == JobStatus::running; }, 60);
  const double latency = since(t0);
  // The preempted job reads queued; its state (in memory until stored, or read back
  // from the store as it resumes) has the trace.
  double in_flight = -1;
  for (size_t i = 0; i < low.size(); ++i) {
    if (m.snapshot(low[i]).status != JobStatus::queued) continue;
    std::shared_ptr<const JobRunner> r = m.snapshot(low[i], JobManager::SnapshotOf::state).runner;
    if (!r) break;  // stored and released already: no figure (printed as -1)
    const auto& trace = r->state().trace;
    for (size_t k = 1; k < trace.size(); ++k) {
      if (trace[k].samples > samples_at_submit[i]) {
        in_flight = trace[k].time_s - trace[k - 1].time_s;
        break;
      }
    }
  }
  std::printf("preemption: %u low-priority 256x256 image jobs on %u workers; a priority-5 job started %.1f ms after\n"
              "  its submit%s (acknowledged, i.e. stored, after %.1f ms); the preempted job's pass in flight took %.1f ms\n"
              "  (latency / pass = %.2f; beyond the pass: %.1f ms); preemptions %llu\n",
              workers, workers, latency * 1e3, started ? "" : " (NOT STARTED)", acknowledged * 1e3, in_flight * 1e3,
              in_flight > 0 ? latency / in_flight : -1.0, (latency - in_flight) * 1e3, static_cast<unsigned long long>(m.stats().preemptions));
  for (const auto& id : low) m.cancel(id);
  m.cancel(urgent);
  wait_for([&] { return m.stats().jobs_by_state.at("running") == 0; }, 60);

  // 2. Cached submit latency for a job that computes for ≥ 10 s.
  const json slow = {{"kind", "integrate"},
                     {"seed", 11},
                     {"integrand", {{"expression", "exp(-x*x-y*y-z*z) * sin(3*x*y*z + 1)"}}},
                     {"domain", {{"type", "box"}, {"lower", {0, 0, 0}}, {"upper", {1, 1, 1}}}},
                     {"stop", {{"max_samples", argc > 2 ? std::strtoull(argv[2], nullptr, 10) : 200000000ULL}}}};
  const auto c0 = Clock::now();
  const std::string first = m.submit(slow, 0)->id();
  wait_for([&] { return m.snapshot(first).status == JobStatus::succeeded; }, 600);
  const double computed = since(c0);
  const auto h0 = Clock::now();
  const auto hit = m.submit(slow, 0);
  const double hit_ms = since(h0) * 1e3;
  const JobSnapshot hs = m.snapshot(*hit);
  std::printf("result cache: the job computed in %.1f s (wall, %u workers); the same spec again answered in "
              "%.2f ms, state %s, cached_from %s, bits %s\n",
              computed, workers, hit_ms, std::string(job_status_name(hs.status)).c_str(), hs.cached_from.c_str(),
              hs.final_result && m.snapshot(first).final_result &&
                      hs.final_result->at("bits") == m.snapshot(first).final_result->at("bits")
                  ? "equal"
                  : "DIFFER");
  m.shutdown();
  store.reset();
  std::filesystem::remove_all(dir);
  return 0;
}
