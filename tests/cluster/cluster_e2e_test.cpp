// Cluster mode end to end: a private redis-server, tally-server --redis and
// tally-worker processes. Every job's result is compared bit for bit with a run of the
// same spec in one process (JobRunner + run_local, i.e. `tally run`, or an in-process
// server for images), through killed, stalled and late workers, a killed coordinator,
// a restarted Redis, cancel and extend, and a block that fails on every worker.
#include <gtest/gtest.h>
#include <OpenImageIO/imageio.h>

#include <bit>
#include <chrono>
#include <fmt/format.h>
#include <fstream>
#include <thread>

#include "cluster_process.hpp"
#include "common/engine/local_executor.hpp"
#include "common/jobs/job_factory.hpp"
#include "server/cluster/assets.hpp"
#include "server_process.hpp"

namespace tally::e2e {
namespace {

using nlohmann::json;
using namespace std::chrono_literals;
namespace fs = std::filesystem;

// The bits `GET /v1/jobs/{id}` reports, from a run of the spec in this process.
// `extend_to` > 0: then extended to that many samples, like POST .../extend.
json local_bits(const json& spec, uint64_t extend_to = 0, const JobLimits& limits = {}) {
  const auto def = compile_job(spec, limits);
  JobRunner runner(def->kernel(), def->stop_rule(), JobCaps{});
  run_local(runner, 2);
  if (extend_to > 0) {
    StopRule rule;
    rule.confidence = runner.rule().confidence;
    rule.min_samples = runner.rule().min_samples;
    rule.max_samples = extend_to;
    runner.extend(rule);
    run_local(runner, 2);
  }
  const Tally& t = runner.state().channels.at(0);
  return {{"n", t.n},
          {"mean", fmt::format("{:016x}", std::bit_cast<uint64_t>(t.mean))},
          {"m2", fmt::format("{:016x}", std::bit_cast<uint64_t>(t.m2))}};
}

std::vector<std::string> cluster_flags(const RedisServer& redis, double lease_s = 30) {
  return {"--redis", redis.url(), "--lease", fmt::format("{}", lease_s), "--checkpoint-interval", "0"};
}

json metrics_counts(HttpClient& c) {
  const json w = get_json(c, "/v1/workers");
  return w.at("results");
}

// Waits (bounded) until `pred` holds.
template <class Pred>
void wait_until(Pred pred, double timeout_s, const std::string& what) {
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
  while (std::chrono::steady_clock::now() < deadline) {
    if (pred()) return;
    std::this_thread::sleep_for(20ms);
  }
  throw std::runtime_error("timed out waiting for " + what);
}

size_t live_workers(HttpClient& c) { return get_json(c, "/v1/workers").at("workers").size(); }

json lighting_image_spec(int spp) {
  std::ifstream in(std::string(TALLY_SOURCE_DIR) + "/examples/lecture_lighting_image.json");
  json spec = json::parse(in);
  spec["scene"]["camera"]["resolution"] = {64, 48};
  spec["stop"] = {{"max_samples", spp}};
  spec["query"].erase("adaptive");
  return spec;
}

std::vector<float> exr_pixels(HttpClient& c, const std::string& id, const fs::path& tmp) {
  const ClientResponse r = c.request("GET", "/v1/jobs/" + id + "/image.exr");
  if (r.status != 200) throw std::runtime_error("image.exr: " + std::to_string(r.status));
  const fs::path file = tmp / (id + ".exr");
  std::ofstream(file, std::ios::binary) << r.body;
  auto in = OIIO::ImageInput::open(file.string());
  if (!in) throw std::runtime_error("cannot open the EXR");
  const OIIO::ImageSpec& spec = in->spec();
  std::vector<float> out;
  for (const char* name : {"R", "G", "B"}) {
    const int ch = spec.channelindex(name);
    if (ch < 0) throw std::runtime_error(std::string("EXR has no channel ") + name);
    std::vector<float> plane(static_cast<size_t>(spec.width) * static_cast<size_t>(spec.height));
    in->read_image(0, 0, ch, ch + 1, OIIO::TypeDesc::FLOAT, plane.data());
    out.insert(out.end(), plane.begin(), plane.end());
  }
  return out;
}

TEST(Cluster, ThreeWorkersMatchInProcessBitsAndPixels) {
  TempDir tmp;
  const json integ = disk_spec(120'000'000, 7);
  const json image = lighting_image_spec(32);
  const json expected_integ = local_bits(integ);
  std::vector<float> expected_pixels;
  json expected_image_bits;
  {
    ServerProcess ref(tmp.path / "ref");
    HttpClient c = ref.client();
    const std::string id = submit(c, image);
    expected_image_bits = wait_state(c, id, "succeeded").at("bits");
    expected_pixels = exr_pixels(c, id, tmp.path);
    ref.terminate();
  }

  RedisServer redis(tmp.path);
  ServerProcess server(tmp.path / "data", cluster_flags(redis));
  std::vector<std::unique_ptr<WorkerProcess>> workers;
  for (int i = 0; i < 3; ++i) workers.push_back(std::make_unique<WorkerProcess>(redis.url(), fmt::format("w{}", i), tmp.path));
  HttpClient c = server.client();
  wait_until([&] { return live_workers(c) == 3; }, 20, "three workers in /v1/workers");
  const std::string a = submit(c, integ);
  const std::string b = submit(c, image);
  const json sa = wait_state(c, a, "succeeded", 120);
  const json sb = wait_state(c, b, "succeeded", 120);
  EXPECT_EQ(sa.at("bits"), expected_integ);
  EXPECT_EQ(sb.at("bits"), expected_image_bits);
  EXPECT_EQ(exr_pixels(c, b, tmp.path), expected_pixels);

  // Every worker took part and is listed with its fields; no block was stored twice.
  // (Counts are refreshed twice a second, heartbeats every second: wait for both.)
  wait_until([&] {
    const json w = get_json(c, "/v1/workers");
    bool all = w.at("workers").size() == 3;
    for (const json& x : w.at("workers")) all = all && x.at("blocks_done").get<uint64_t>() > 0;
    return all && w.at("results").at("first") == w.at("results").at("blocks_merged");
  }, 10, "the worker registry and result counts to catch up");
  const json w = get_json(c, "/v1/workers");
  ASSERT_EQ(w.at("workers").size(), 3u);
  for (const json& x : w.at("workers")) {
    EXPECT_GT(x.at("blocks_done").get<uint64_t>(), 0u) << x.dump();
    EXPECT_EQ(x.at("threads"), 1);
    EXPECT_FALSE(x.at("host").get<std::string>().empty());
    EXPECT_LT(x.at("seconds_since_heartbeat").get<double>(), 10.0);
  }
  EXPECT_EQ(w.at("results").at("first"), w.at("results").at("blocks_merged"));
  EXPECT_EQ(w.at("results").at("duplicates_different"), 0);
  const std::string metrics = c.request("GET", "/metrics").body;
  EXPECT_NE(metrics.find("tally_cluster_workers 3"), std::string::npos);
  EXPECT_NE(metrics.find("tally_cluster_redis_up 1"), std::string::npos);
  EXPECT_EQ(c.request("GET", "/readyz").status, 200);

  // Per-pass streams and results are deleted once merged: nothing of the jobs is left.
  auto rc = redis.connect();
  EXPECT_EQ(rc.cmd({"KEYS", "tally:[sprfd]:*"}).elems.size(), 0u);
  EXPECT_EQ(rc.cmd({"KEYS", "tally:job:*"}).elems.size(), 0u);
  EXPECT_EQ(rc.cmd({"SCARD", "tally:active"}).as_int(), 0);
}

// Which consumer of `prefix` holds a pending entry of an active stream, if any.
bool holds_entry(cluster::RedisConn& rc, const std::string& worker) {
  for (const auto& s : rc.cmd({"SMEMBERS", "tally:active"}).elems) {
    try {
      const auto p = rc.cmd({"XPENDING", s.str, "w", "-", "+", "100"});
      for (const auto& e : p.elems) {
        if (e.elems.size() >= 2 && e.elems[1].str.rfind(worker + "/", 0) == 0) return true;
      }
    } catch (const cluster::RedisReplyError&) {
    }
  }
  return false;
}

TEST(Cluster, KilledAndStalledWorkersStillBitIdentical) {
  TempDir tmp;
  const json spec = disk_spec(400'000'000, 11);
  const json expected = local_bits(spec);
  RedisServer redis(tmp.path);
  ServerProcess server(tmp.path / "data", cluster_flags(redis, 1.0));
  WorkerProcess a(redis.url(), "a", tmp.path), b(redis.url(), "b", tmp.path), d(redis.url(), "d", tmp.path);
  HttpClient c = server.client();
  wait_until([&] { return live_workers(c) == 3; }, 20, "three workers");
  const std::string id = submit(c, spec);
  wait_until([&] { return get_json(c, "/v1/jobs/" + id).at("samples").get<uint64_t>() > 20'000'000; }, 60,
             "the job to be under way");
  auto rc = redis.connect();
  // kill -9 a worker while it holds a block.
  wait_until([&] { return holds_entry(rc, "a"); }, 20, "worker a to hold a block");
  a.kill9();
  // SIGSTOP another while it holds a block, past its 1 s lease, then SIGCONT.
  bool stopped_holding = false;
  for (int i = 0; i < 400 && !stopped_holding; ++i) {
    b.pause();
    if (holds_entry(rc, "b")) {
      stopped_holding = true;
    } else {
      b.resume();
      std::this_thread::sleep_for(10ms);
    }
  }
  ASSERT_TRUE(stopped_holding) << "worker b never held a block";
  std::this_thread::sleep_for(2500ms);  // 2.5 leases: its block is reclaimed and computed by d
  EXPECT_FALSE(holds_entry(rc, "b")) << "the stalled worker's block was not reclaimed";
  ASSERT_EQ(get_json(c, "/v1/jobs/" + id).at("state"), "running") << "the job ended before the stalled worker resumed";
  b.resume();
  const json s = wait_state(c, id, "succeeded", 120);
  EXPECT_EQ(s.at("bits"), expected);
  std::this_thread::sleep_for(1200ms);  // the counts are refreshed twice a second
  const json r = metrics_counts(c);
  EXPECT_EQ(r.at("first"), r.at("blocks_merged")) << r.dump();  // no block merged (or stored) twice
  EXPECT_GE(r.at("duplicates_equal").get<uint64_t>(), 1u) << r.dump() << b.log();  // the late result, compared
  EXPECT_EQ(r.at("duplicates_different"), 0);
  EXPECT_NE(b.log().find("compared, identical"), std::string::npos) << b.log();
}

TEST(Cluster, CoordinatorKilledMidPassResumesBitIdentical) {
  TempDir tmp;
  const json spec = disk_spec(200'000'000, 5);
  const json expected = local_bits(spec);
  RedisServer redis(tmp.path);
  ServerProcess server(tmp.path / "data", cluster_flags(redis));
  WorkerProcess w1(redis.url(), "w1", tmp.path), w2(redis.url(), "w2", tmp.path);
  HttpClient c = server.client();
  wait_until([&] { return live_workers(c) == 2; }, 20, "two workers");
  const std::string id = submit(c, spec);
  auto rc = redis.connect();
  wait_until([&] { return get_json(c, "/v1/jobs/" + id).at("samples").get<uint64_t>() > 50'000'000 &&
                          rc.cmd({"SCARD", "tally:active"}).as_int() > 0; },
             60, "the job mid-pass");
  server.kill9();
  std::this_thread::sleep_for(300ms);
  server.start();
  HttpClient c2 = server.client();
  const json s = wait_state(c2, id, "succeeded", 120);
  EXPECT_EQ(s.at("bits"), expected);
}

TEST(Cluster, RedisRestartMidJobRepublishesAndUnreachableRedisPauses) {
  TempDir tmp;
  const json spec = disk_spec(200'000'000, 9);
  const json expected = local_bits(spec);
  RedisServer redis(tmp.path);
  ServerProcess server(tmp.path / "data", cluster_flags(redis));
  WorkerProcess w1(redis.url(), "w1", tmp.path), w2(redis.url(), "w2", tmp.path);
  HttpClient c = server.client();
  wait_until([&] { return live_workers(c) == 2; }, 20, "two workers");
  const std::string id = submit(c, spec);
  wait_until([&] { return get_json(c, "/v1/jobs/" + id).at("samples").get<uint64_t>() > 50'000'000; }, 60,
             "the job under way");
  redis.stop();
  // Unreachable: /readyz says why, the job is paused (not failed) and says so.
  wait_until([&] { return c.request("GET", "/readyz").status == 503; }, 10, "/readyz to fail");
  EXPECT_NE(c.request("GET", "/readyz").body.find("redis unreachable"), std::string::npos);
  wait_until([&] { return get_json(c, "/v1/jobs/" + id).value("waiting_reason", "").find("redis unreachable") !=
                          std::string::npos; },
             5, "the job's status to say it is paused");
  EXPECT_EQ(get_json(c, "/v1/jobs/" + id).at("state"), "running");
  std::this_thread::sleep_for(1s);
  redis.start();  // empty: no streams, no groups, no results
  wait_until([&] { return c.request("GET", "/readyz").status == 200; }, 20, "/readyz to recover");
  const json s = wait_state(c, id, "succeeded", 120);
  EXPECT_EQ(s.at("bits"), expected);
  EXPECT_GE(metrics_counts(c).at("passes_republished").get<uint64_t>(), 1u);
}

TEST(Cluster, CancelAndExtendAcrossTheCluster) {
  TempDir tmp;
  RedisServer redis(tmp.path);
  ServerProcess server(tmp.path / "data", cluster_flags(redis));
  WorkerProcess w1(redis.url(), "w1", tmp.path), w2(redis.url(), "w2", tmp.path);
  HttpClient c = server.client();
  wait_until([&] { return live_workers(c) == 2; }, 20, "two workers");

  // Cancel: the job stops within about one block and nothing of it stays in Redis.
  const std::string big = submit(c, disk_spec(50'000'000'000ULL, 3));
  wait_until([&] { return get_json(c, "/v1/jobs/" + big).at("samples").get<uint64_t>() > 0; }, 60, "progress");
  ASSERT_EQ(c.request("DELETE", "/v1/jobs/" + big).status, 202);
  const json cancelled = wait_state(c, big, "cancelled", 10);
  auto rc = redis.connect();
  wait_until([&] { return rc.cmd({"KEYS", "tally:[sprf]:" + big + ":*"}).elems.empty(); }, 5, "the job's keys to go");
  const uint64_t samples = cancelled.at("samples").get<uint64_t>();
  std::this_thread::sleep_for(500ms);
  EXPECT_EQ(get_json(c, "/v1/jobs/" + big).at("samples").get<uint64_t>(), samples);  // no late merge

  // Extend: the reopened job ends bit-identical to the same extend in one process.
  const json first = disk_spec(40'000'000, 4);
  const json expected = local_bits(first, 90'000'000);
  const std::string id = submit(c, first);
  wait_state(c, id, "succeeded", 60);
  const ClientResponse ext = c.request("POST", "/v1/jobs/" + id + "/extend", json{{"max_samples", 90'000'000}}.dump(),
                                       {{"Content-Type", "application/json"}});
  ASSERT_EQ(ext.status, 202) << ext.body;
  const json s = wait_state(c, id, "succeeded", 60);
  EXPECT_EQ(s.at("bits"), expected);
}

TEST(Cluster, NoWorkerMeansTheJobWaitsAndLateWorkersTakePart) {
  TempDir tmp;
  const json spec = disk_spec(300'000'000, 13);
  const json expected = local_bits(spec);
  RedisServer redis(tmp.path);
  ServerProcess server(tmp.path / "data", cluster_flags(redis));
  HttpClient c = server.client();
  const std::string id = submit(c, spec);
  std::this_thread::sleep_for(1500ms);
  const json waiting = get_json(c, "/v1/jobs/" + id);
  EXPECT_EQ(waiting.at("state"), "running");
  EXPECT_EQ(waiting.at("samples"), 0);
  EXPECT_NE(waiting.value("waiting_reason", "").find("waiting for a tally-worker"), std::string::npos) << waiting.dump();
  EXPECT_GT(waiting.at("blocks").at("pending").get<uint64_t>(), 0u) << waiting.dump();

  WorkerProcess first(redis.url(), "first", tmp.path);
  wait_until([&] { return get_json(c, "/v1/jobs/" + id).at("samples").get<uint64_t>() > 20'000'000; }, 60,
             "progress with one worker");
  WorkerProcess late(redis.url(), "late", tmp.path);  // joins a job in flight
  wait_until([&] { return live_workers(c) == 2; }, 20, "the late worker to register");
  ASSERT_EQ(get_json(c, "/v1/jobs/" + id).at("state"), "running") << "the job ended before the late worker joined";
  const json s = wait_state(c, id, "succeeded", 120);
  EXPECT_EQ(s.at("bits"), expected);
  EXPECT_FALSE(s.contains("waiting_reason"));
  // The late worker took part (its heartbeat reports its blocks within a second).
  EXPECT_NO_THROW(wait_until([&] {
    const json all = get_json(c, "/v1/workers");  // (a range-for over a temporary's member dangles)
    for (const json& w : all.at("workers")) {
      if (w.at("name") == "late" && w.at("blocks_done").get<uint64_t>() > 0) return true;
    }
    return false;
  }, 5, "the late worker's blocks")) << get_json(c, "/v1/workers").dump();
}

TEST(Cluster, BlockFailingOnEveryWorkerFailsTheJobAfterNDeliveries) {
  TempDir tmp;
  RedisServer redis(tmp.path);
  std::vector<std::string> flags = cluster_flags(redis);
  flags.insert(flags.end(), {"--max-deliveries", "4"});
  ServerProcess server(tmp.path / "data", flags);
  // These workers refuse what the server accepts (more than 2 dimensions): every
  // delivery of every block fails on every worker with the worker's error.
  WorkerProcess w1(redis.url(), "strict1", tmp.path, 1, {"--max-dimensions", "2"});
  WorkerProcess w2(redis.url(), "strict2", tmp.path, 1, {"--max-dimensions", "2"});
  HttpClient c = server.client();
  wait_until([&] { return live_workers(c) == 2; }, 20, "two workers");
  json spec = {{"kind", "integrate"},
               {"integrand", {{"expression", "x0*x1*x2"}}},
               {"domain", {{"type", "box"}, {"lower", {0, 0, 0}}, {"upper", {1, 1, 1}}}},
               {"seed", 1},
               {"stop", {{"max_samples", 1'000'000}}}};
  const std::string id = submit(c, spec);
  const json s = wait_state(c, id, "failed", 30);
  const std::string msg = s.value("error_message", "");
  EXPECT_NE(msg.find("the worker refused the spec"), std::string::npos) << msg;
  EXPECT_NE(msg.find("/domain"), std::string::npos) << msg;
  EXPECT_NE(msg.find("failed on worker strict"), std::string::npos) << msg;
  EXPECT_NO_THROW(wait_until([&] { return metrics_counts(c).at("failed_deliveries").get<uint64_t>() >= 4; }, 5,
                             "four failed deliveries counted"))
      << metrics_counts(c).dump();
  EXPECT_EQ(metrics_counts(c).at("first"), 0);
}

TEST(Cluster, ObjAssetsReachWorkersWithoutASharedDirectory) {
  TempDir tmp;
  const fs::path assets = tmp.path / "assets";
  fs::create_directories(assets / "meshes");
  const std::string obj = "v -0.5 -0.5 1.5\nv -0.5 0.5 1.5\nv 0.5 0.5 1.5\nv 0.5 -0.5 1.5\nf 1 2 3\nf 1 3 4\n";
  std::ofstream(assets / "meshes" / "lamp.obj") << obj;
  json spec = lighting_image_spec(4);
  spec["scene"]["camera"]["resolution"] = {32, 24};
  spec["scene"]["shapes"].push_back({{"type", "mesh"}, {"obj", "meshes/lamp.obj"}, {"material", "lamp"}});
  JobLimits limits;
  limits.asset_dir = assets.string();
  const json expected = local_bits(spec, 0, limits);

  RedisServer redis(tmp.path);
  std::vector<std::string> flags = cluster_flags(redis);
  flags.insert(flags.end(), {"--asset-dir", assets.string()});
  ServerProcess server(tmp.path / "data", flags);
  // The workers have no --asset-dir and their own cache: the file can only come through Redis.
  WorkerProcess w1(redis.url(), "w1", tmp.path, 1, {"--cache-dir", (tmp.path / "cache1").string()});
  HttpClient c = server.client();
  wait_until([&] { return live_workers(c) == 1; }, 20, "a worker");
  const std::string id = submit(c, spec);
  const json s = wait_state(c, id, "succeeded", 60);
  EXPECT_EQ(s.at("bits"), expected);
  auto rc = redis.connect();
  const std::string sha = cluster::sha256_hex(obj);
  EXPECT_EQ(rc.cmd({"GET", "tally:asset:" + sha}).str, obj);  // content-addressed
  EXPECT_TRUE(fs::exists(tmp.path / "cache1" / "blobs" / sha));
}

}  // namespace
}  // namespace tally::e2e

namespace tally::e2e {
namespace {

// An asset uploaded to the server (PUT /v1/assets) and named by hash reaches workers that
// share nothing with the server but Redis; the result is bit-identical to the same file
// given as a path in process.
TEST(Cluster, UploadedAssetsReachWorkersByHash) {
  TempDir tmp;
  const fs::path assets = tmp.path / "assets";
  fs::create_directories(assets);
  const std::string obj = "v -0.4 -0.4 1.4\nv -0.4 0.4 1.4\nv 0.4 0.4 1.4\nv 0.4 -0.4 1.4\nf 1 2 3\nf 1 3 4\n";
  std::ofstream(assets / "lamp.obj") << obj;
  json spec = lighting_image_spec(4);
  spec["scene"]["camera"]["resolution"] = {32, 24};
  spec["scene"]["shapes"].push_back({{"type", "mesh"}, {"obj", "lamp.obj"}, {"material", "lamp"}});
  JobLimits limits;
  limits.asset_dir = assets.string();
  const json expected = local_bits(spec, 0, limits);

  RedisServer redis(tmp.path);
  ServerProcess server(tmp.path / "data", cluster_flags(redis));  // no --asset-dir
  WorkerProcess w1(redis.url(), "w1", tmp.path, 1, {"--cache-dir", (tmp.path / "cache1").string()});
  HttpClient c = server.client();
  wait_until([&] { return live_workers(c) == 1; }, 20, "a worker");
  const std::string sha = cluster::sha256_hex(obj);
  ASSERT_EQ(c.request("PUT", "/v1/assets/sha256:" + sha, obj).status, 201);
  spec["scene"]["shapes"].back()["obj"] = "sha256:" + sha;
  const std::string id = submit(c, spec);
  const json s = wait_state(c, id, "succeeded", 60);
  EXPECT_EQ(s.at("bits"), expected);
  auto rc = redis.connect();
  EXPECT_EQ(rc.cmd({"GET", "tally:asset:" + sha}).str, obj);
  EXPECT_TRUE(fs::exists(tmp.path / "cache1" / "blobs" / sha));  // the worker's store, checked against the hash
}

}  // namespace
}  // namespace tally::e2e
