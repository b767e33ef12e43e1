// Preemption in cluster mode (issue 32; docs/api.md "Preemption"): with --max-running 1
// a priority-5 submit pauses the running low-priority job at its next pass boundary even
// when the passes are computed by tally-worker processes through Redis; the paused job
// reads as queued with waiting_reason "preempted", resumes when the urgent job is done,
// and ends with the bits of a run nobody paused.
#include <gtest/gtest.h>

#include <atomic>
#include <thread>

#include "cluster_process.hpp"
#include "cluster_test_support.hpp"
#include "server_process.hpp"

namespace tally::e2e {
namespace {

TEST(ClusterPreemption, UrgentJobPausesTheRunningOneWhichResumesBitIdentical) {
  TempDir tmp;
  // Many passes (the schedule doubles from a small first pass), each short on one worker.
  const json low = disk_spec(200'000'000, 31), urgent = disk_spec(2'000'000, 32);
  const json expected_low = local_bits(low), expected_urgent = local_bits(urgent);
  TestCluster cl(tmp.path, {{"w1", 2}}, {30, {"--max-running", "1", "--preempt-min-run", "0"}});
  HttpClient& c = cl.c;

  const std::string a = submit(c, low, "?priority=-5");
  wait_until([&] { return get_json(c, "/v1/jobs/" + a).value("samples", 0) > 0; }, 60, "the low job's first pass");

  // Watch the low job's status from its own connection while the urgent one runs.
  std::atomic<bool> stop{false}, seen_preempted{false};
  HttpClient watcher = cl.server.client();
  std::thread watch([&] {
    while (!stop) {
      const json s = get_json(watcher, "/v1/jobs/" + a);
      if (s.at("state") == "queued" && s.value("waiting_reason", "") == "preempted") seen_preempted = true;
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
  });
  const uint64_t low_samples_at_submit = get_json(c, "/v1/jobs/" + a).value("samples", uint64_t{0});
  const auto t0 = std::chrono::steady_clock::now();
  const std::string b = submit(c, urgent, "?priority=5");
  double started_ms = -1;
  wait_until(
      [&] {
        if (started_ms < 0 && get_json(c, "/v1/jobs/" + b).at("state") != "queued") {
          started_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
        }
        return started_ms >= 0;
      },
      60, "the urgent job to start");
  const json sb = wait_state(c, b, "succeeded", 120);
  const json sa_mid = get_json(c, "/v1/jobs/" + a);
  const json sa = wait_state(c, a, "succeeded", 180);
  stop = true;
  watch.join();

  // The pass in flight when the urgent job came: the first of the low job's passes whose
  // count passed the samples it had then, from its final trace (points are [compute time
  // s, samples, mean, std error] per pass; a pass's compute time is its wall time).
  const json trace = sa.value("trace", json::array());
  double pass_ms = -1;
  for (size_t i = 1; i < trace.size(); ++i) {
    if (trace[i][1].get<uint64_t>() > low_samples_at_submit) {
      pass_ms = 1e3 * (trace[i][0].get<double>() - trace[i - 1][0].get<double>());
      break;
    }
  }
  std::printf("cluster preemption: the priority-5 job started %.0f ms after its submit; the low job's pass in flight "
              "took %.0f ms (%.2f pass lengths)\n",
              started_ms, pass_ms, pass_ms > 0 ? started_ms / pass_ms : -1.0);
  EXPECT_TRUE(seen_preempted) << "the low job never read as queued/preempted; while the urgent ran: " << sa_mid.dump();
  EXPECT_GE(metric(c, "tally_preemptions_total"), 1);
  EXPECT_EQ(sb.at("bits"), expected_urgent);
  EXPECT_EQ(sa.at("bits"), expected_low) << "the preempted job resumed bit-identically";
  EXPECT_EQ(sa.at("samples"), 200'000'000);
  EXPECT_EQ(get_json(c, "/v1/workers").at("results").at("duplicates_different"), 0);
}

}  // namespace
}  // namespace tally::e2e
