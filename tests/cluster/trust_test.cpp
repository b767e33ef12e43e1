// What the cluster checks of what it reads from Redis, and how it reports Redis's own
// health (docs/security.md "Cluster mode", docs/cluster.md): results changed in Redis
// fail the job (a keyed digest with --result-key-file; a count above the planned
// samples always), a spec written into Redis without the key is refused, /metrics
// names no job, and Redis out of memory is named as such while the job waits and then
// finishes bit-identical.
#include <gtest/gtest.h>

#include <bit>
#include <fmt/format.h>
#include <fstream>
#include <set>
#include <signal.h>
#include <thread>

#include "cluster_process.hpp"
#include "cluster_test_support.hpp"
#include "server/cluster/wire.hpp"
#include "server_process.hpp"

namespace tally::e2e {
namespace {

fs::path write_key(const fs::path& dir) {
  const fs::path p = dir / "result.key";
  std::ofstream(p) << "0123456789abcdef0123456789abcdef0123456789abcdef\n";
  return p;
}

// Changes the stored results of one entry of job `id` that the coordinator has not read
// yet (it reads them as they land): the coordinator is stopped (SIGSTOP) while the
// worker stores a few more entries, then the worker too, and one of the entries stored
// meanwhile is changed before both go on. `change` edits the decoded results; with
// `rehash`, the unkeyed digest is recomputed too, as an attacker who can write to Redis
// would.
template <class Change>
void tamper_one_entry(TestCluster& cl, const std::string& id, Change change, bool rehash) {
  auto rc = cl.redis.connect();
  auto stored = [&] {
    std::set<std::pair<std::string, std::string>> s;  // {id}:{run}:{pass}, first slot
    for (const auto& k : rc.cmd({"KEYS", "tally:r:" + id + ":*"}).elems) {
      for (const auto& slot : rc.cmd({"HKEYS", k.str}).elems) s.emplace(k.str.substr(8), slot.str);
    }
    return s;
  };
  for (int attempt = 0; attempt < 50; ++attempt) {
    cl.server.signal(SIGSTOP);
    const auto before = stored();
    std::this_thread::sleep_for(300ms);
    cl.worker(0).pause();
    for (const auto& [rest, slot] : stored()) {
      if (before.count({rest, slot})) continue;
      const std::string vk = "tally:v:" + rest + ":" + slot;
      const std::string old = rc.cmd({"GET", vk}).str;
      std::vector<BlockResult> results = cluster::decode_entry_results(old);
      change(results.front());
      std::string bytes;
      for (const BlockResult& r : results) cluster::append_entry_result(bytes, cluster::encode_result(r));
      EXPECT_NE(bytes, old);
      rc.cmd({"SET", vk, bytes});
      if (rehash) rc.cmd({"HSET", "tally:d:" + rest, slot, cluster::result_digest(bytes)});
      cl.worker(0).resume();
      cl.server.signal(SIGCONT);
      return;
    }
    cl.worker(0).resume();
    cl.server.signal(SIGCONT);
    std::this_thread::sleep_for(100ms);
  }
  FAIL() << "no entry stored while the coordinator was stopped";
}

void flip_mean_bit(BlockResult& r) {
  r.tallies.at(0).mean = std::bit_cast<double>(std::bit_cast<uint64_t>(r.tallies.at(0).mean) ^ 1u);
}

// With --result-key-file on the server and the workers: a job computes as before
// (bits equal in process); one whose stored result is changed in Redis (a bit of a
// mean, with its SHA-1 recomputed) fails naming the keyed digest instead of succeeding
// with other bits.
TEST(ClusterTrust, AChangedResultFailsTheJobOnItsKeyedDigest) {
  TempDir tmp;
  const fs::path key = write_key(tmp.path);
  const json good = disk_spec(30'000'000, 31), spec = disk_spec(400'000'000, 32);
  const json expected = local_bits(good);
  TestCluster cl(tmp.path, {{"w0", 1, {"--result-key-file", key.string()}}},
                 {30, {"--result-key-file", key.string()}});
  HttpClient& c = cl.c;
  const std::string ok = submit(c, good);
  EXPECT_EQ(wait_state(c, ok, "succeeded", 120).at("bits"), expected);

  const std::string id = submit(c, spec);
  tamper_one_entry(cl, id, flip_mean_bit, true);
  const json s = wait_state(c, id, "failed", 120);
  const std::string msg = s.value("error_message", "");
  EXPECT_NE(msg.find("do not match their keyed (HMAC-SHA-256) digest"), std::string::npos) << msg;
}

// Without a key, a count above the samples the group's blocks planned (the result's n
// raised by one, its SHA-1 recomputed) fails the job instead of merging n = samples + 1.
TEST(ClusterTrust, AResultCountingMoreSamplesThanPlannedFailsTheJob) {
  TempDir tmp;
  TestCluster cl(tmp.path, {{"w0", 1}});
  HttpClient& c = cl.c;
  const std::string id = submit(c, disk_spec(400'000'000, 33));
  tamper_one_entry(cl, id, [](BlockResult& r) { r.tallies.at(0).n += 1; }, true);
  const json s = wait_state(c, id, "failed", 120);
  const std::string msg = s.value("error_message", "");
  EXPECT_NE(msg.find("samples in channel 0, but its blocks hold"), std::string::npos) << msg;
}

// A valid spec written into the job's Redis hash by someone without the key is refused
// by the worker (its MAC does not match): the job fails saying so, and the substitute
// never runs.
TEST(ClusterTrust, ASpecWrittenIntoRedisWithoutTheKeyIsRefused) {
  TempDir tmp;
  const fs::path key = write_key(tmp.path);
  TestCluster cl(tmp.path, {}, {30, {"--result-key-file", key.string(), "--max-deliveries", "2"}});
  HttpClient& c = cl.c;
  const std::string id = submit(c, disk_spec(20'000'000, 34));
  auto rc = cl.redis.connect();
  wait_until([&] { return !rc.cmd({"HGET", "tally:job:" + id, "spec"}).is_nil(); }, 20, "the job hash");
  rc.cmd({"HSET", "tally:job:" + id, "spec", disk_spec(20'000'000, 99).dump()});
  WorkerProcess w(cl.redis.url(), "w0", tmp.path, 1, {"--result-key-file", key.string()});
  const json s = wait_state(c, id, "failed", 60);
  const std::string msg = s.value("error_message", "");
  EXPECT_NE(msg.find("does not match its MAC"), std::string::npos) << msg;
}

// /metrics lists no tenant's job id: the blocks of running jobs are one sum per state.
TEST(ClusterTrust, MetricsNameNoJob) {
  TempDir tmp;
  TestCluster cl(tmp.path, {});
  HttpClient& c = cl.c;
  const std::string id = submit(c, disk_spec(50'000'000, 35));
  wait_until([&] { return get_json(c, "/v1/jobs/" + id).contains("blocks"); }, 20, "the job in the coordinator");
  std::string metrics;
  wait_until([&] {
    metrics = c.request("GET", "/metrics").body;
    return metrics.find("tally_cluster_blocks{state=\"pending\"} 0\n") == std::string::npos &&
           metrics.find("tally_cluster_blocks{state=\"pending\"}") != std::string::npos;
  }, 10, "pending blocks in /metrics");
  EXPECT_EQ(metrics.find(id), std::string::npos) << metrics;
}

// Redis out of memory (maxmemory set below what it holds, mid-job): the job neither
// fails ("delivered N times") nor blames missing workers: its waiting_reason and
// /readyz name Redis's memory, the worker holds its computed results, and once Redis
// has room again the job finishes bit-identical to a run in one process.
TEST(ClusterTrust, RedisOutOfMemoryIsNamedAndTheJobResumesBitIdentical) {
  TempDir tmp;
  const json spec = disk_spec(300'000'000, 36);
  const json expected = local_bits(spec);
  TestCluster cl(tmp.path, {{"w0", 1}}, {1.0});
  HttpClient& c = cl.c;
  const std::string id = submit(c, spec);
  wait_until([&] { return get_json(c, "/v1/jobs/" + id).at("samples").get<uint64_t>() > 0; }, 60, "progress");
  auto rc = cl.redis.connect();
  rc.cmd({"CONFIG", "SET", "maxmemory", "1"});
  json waiting;
  wait_until([&] {
    waiting = get_json(c, "/v1/jobs/" + id);
    return waiting.value("waiting_reason", "").find("out of memory") != std::string::npos;
  }, 10, "the waiting reason to name Redis's memory");
  EXPECT_NE(waiting.at("waiting_reason").get<std::string>().find("maxmemory"), std::string::npos) << waiting.dump();
  const ClientResponse ready = c.request("GET", "/readyz");
  EXPECT_EQ(ready.status, 503);
  EXPECT_NE(ready.body.find("out of memory"), std::string::npos) << ready.body;
  EXPECT_NE(c.request("GET", "/metrics").body.find("tally_cluster_redis_out_of_memory 1\n"), std::string::npos);
  // Eight leases of 1 s: more than --max-deliveries + 2 deliveries' worth.
  for (int i = 0; i < 80; ++i) {
    ASSERT_NE(get_json(c, "/v1/jobs/" + id).at("state"), "failed") << get_json(c, "/v1/jobs/" + id).dump();
    std::this_thread::sleep_for(100ms);
  }
  rc.cmd({"CONFIG", "SET", "maxmemory", "0"});
  const json s = wait_state(c, id, "succeeded", 120);
  EXPECT_EQ(s.at("bits"), expected);
  wait_until([&] { return c.request("GET", "/readyz").status == 200; }, 10, "/readyz to recover");
}

}  // namespace
}  // namespace tally::e2e
