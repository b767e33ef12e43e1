// Cluster mode end to end: a private redis-server, tally-server --redis and
// tally-worker processes. Every job's result is compared bit for bit with a run of the
// same spec in one process (JobRunner + run_local, i.e. `tally run`, or an in-process
// server for images), through killed, stalled and late workers, a killed coordinator,
// a restarted Redis, cancel and extend, and a block that fails on every worker.
#include <gtest/gtest.h>
#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>

#include <bit>
#include <chrono>
#include <fmt/format.h>
#include <fstream>
#include <thread>

#include "../lighting/gltf/gltf_writer.hpp"
#include "cluster_process.hpp"
#include "cluster_test_support.hpp"
#include "common/engine/pass_loop.hpp"
#include "common/protocol/job_kinds.hpp"
#include "server/cluster/assets.hpp"
#include "server/cluster/redis_layout.hpp"
#include "server/cluster/wire.hpp"
#include "server_process.hpp"

namespace tally::e2e {
namespace {

using nlohmann::json;
using namespace std::chrono_literals;
namespace fs = std::filesystem;

TEST(Cluster, ThreeWorkersMatchInProcessBitsAndPixels) {
  TempDir tmp;
  const json integ = disk_spec(120'000'000, 7);
  // 64 spp: the 32-spp pass gives each tile 2 blocks of 16 spp, one result group that
  // the worker combines (PassSchedule::group_blocks), as the unit-disk passes' groups of 16.
  const json image = lighting_image_spec(64);
  const json expected_integ = local_bits(integ);
  const ImageReference expected = in_process_image(tmp.path, image);

  TestCluster cl(tmp.path, {{"w0"}, {"w1"}, {"w2"}});
  HttpClient& c = cl.c;
  const std::string a = submit(c, integ);
  const std::string b = submit(c, image);
  const json sa = wait_state(c, a, "succeeded", 120);
  const json sb = wait_state(c, b, "succeeded", 120);
  EXPECT_EQ(sa.at("bits"), expected_integ);
  EXPECT_EQ(sb.at("bits"), expected.bits);
  EXPECT_EQ(exr_pixels(c, b, tmp.path), expected.pixels);

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
  // Both jobs plan from counts (a sample limit, no adaptive tiles): each pass after the
  // first was out before the one before it was merged, and the bits above still match.
  EXPECT_GT(w.at("results").at("passes_published_ahead").get<uint64_t>(), 0u) << w.dump();
  const std::string metrics = c.request("GET", "/metrics").body;
  EXPECT_NE(metrics.find("tally_cluster_workers 3"), std::string::npos);
  EXPECT_NE(metrics.find("tally_cluster_redis_up 1"), std::string::npos);
  EXPECT_EQ(c.request("GET", "/readyz").status, 200);

  // Per-pass streams and results are deleted once merged: nothing of the jobs is left.
  auto rc = cl.redis.connect();
  EXPECT_EQ(rc.cmd({"KEYS", "tally:[sprfdv]:*"}).elems.size(), 0u);
  // Every upload was moved into place or deleted by the store script.
  EXPECT_EQ(rc.cmd({"KEYS", "tally:upload:*"}).elems.size(), 0u);
  EXPECT_EQ(rc.cmd({"KEYS", "tally:job:*"}).elems.size(), 0u);
  EXPECT_EQ(rc.cmd({"SCARD", "tally:active"}).as_int(), 0);
}

// A worker alone on one job reads each pass's next entry with the store of the entry
// before (one round trip per entry, not two): only the first entry of each pass, per
// thread, is read on its own. Counted from the worker's --verbose lines; the bits stay
// those of an in-process run.
TEST(Cluster, AWorkerAloneOnAJobReadsTheNextEntryWithEachStore) {
  TempDir tmp;
  const json integ = disk_spec(120'000'000, 7);
  const json expected = local_bits(integ);
  TestCluster cl(tmp.path, {{"w0", 2, {"--verbose"}}});
  const std::string id = submit(cl.c, integ);
  const json st = wait_state(cl.c, id, "succeeded", 120);
  EXPECT_EQ(st.at("bits"), expected);
  const uint64_t passes = st.at("passes").get<uint64_t>();
  EXPECT_EQ(cl.worker(0).terminate(), 0);
  const std::string log = cl.worker(0).log();
  size_t read_on = 0, alone = 0;
  for (size_t at = 0; (at = log.find("got at unix", at)) != std::string::npos; ++at) {
    const size_t eol = log.find('\n', at);
    const std::string line = log.substr(at, eol - at);
    if (line.find("with the store before") != std::string::npos) ++read_on;
    if (line.find("by a read of its own") != std::string::npos) ++alone;
  }
  // A read of its own starts a chain that ends only when that pass's stream has no entry
  // left (no entry is added to a pass's stream after it is published), so each thread
  // reads at most one entry of each pass on its own (no worker died here: no reclaims).
  // Without reading on, every entry would be read on its own.
  ASSERT_GT(read_on + alone, 2 * passes) << "too few entries per pass for the test to tell";
  EXPECT_LE(alone, 2 * passes) << "read on " << read_on << ", passes " << passes;
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

// Issue 15: an adaptive job (VEGAS+: the grid and the hypercube allocation travel as
// pass input, their per-block sums back as aux) and a deterministic cubature job (one
// block) on two workers end with the bits and the result of an in-process run.
TEST(Cluster, VegasPlusAndCubatureJobsMatchInProcessBits) {
  TempDir tmp;
  const json genz = {{"builtin", "genz"}, {"family", "discontinuous"}, {"a", {3.0, 5.0, 2.0}}, {"u", {0.6, 0.45, 0.5}}};
  const json vegas = {{"kind", "integrate"}, {"seed", 5}, {"integrand", genz},
                      {"estimator", {{"type", "vegas"}, {"stratify", true}}}, {"stop", {{"max_samples", 4096 * 63}}}};
  const json cubature = {{"kind", "integrate"}, {"integrand", genz}, {"estimator", {{"type", "cubature"}}},
                         {"stop", {{"rel_error", 1e-6}, {"max_samples", 100000}}}};
  TestCluster cl(tmp.path, {{"w0"}, {"w1"}});
  HttpClient& c = cl.c;
  for (const json& spec : {vegas, cubature}) {
    const std::string id = submit(c, spec);
    const json s = wait_state(c, id, "succeeded", 120);
    EXPECT_EQ(s.at("bits"), local_bits(spec)) << spec.at("estimator").dump();
    const auto def = compile_job(spec, JobLimits{});
    JobRunner runner(def->kernel(), def->stop_rule(), JobCaps{});
    run_local(runner, 1);
    EXPECT_EQ(s.at("result"), kind_result_json(*def, runner)) << spec.at("estimator").dump();
  }
}

TEST(Cluster, KilledAndStalledWorkersStillBitIdentical) {
  TempDir tmp;
  const json spec = disk_spec(400'000'000, 11);
  const json expected = local_bits(spec);
  TestCluster cl(tmp.path, {{"a"}, {"b"}, {"d"}}, {.lease_s = 1.0});
  HttpClient& c = cl.c;
  WorkerProcess &a = cl.worker(0), &b = cl.worker(1);
  const std::string id = submit(c, spec);
  wait_until([&] { return get_json(c, "/v1/jobs/" + id).at("samples").get<uint64_t>() > 20'000'000; }, 60,
             "the job to be under way");
  auto rc = cl.redis.connect();
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
  // The stalled worker's late result arrives: compared with the first (its pass not yet
  // merged) or found stale (merged and deleted already; which one depends on timing).
  // The counts are refreshed twice a second.
  wait_until([&] {
    const json r = metrics_counts(c);
    return r.at("duplicates_equal").get<uint64_t>() + r.at("stale").get<uint64_t>() >= 1;
  }, 60, "the stalled worker's late result");
  std::this_thread::sleep_for(1200ms);
  const json r = metrics_counts(c);
  EXPECT_EQ(r.at("first"), r.at("blocks_merged")) << r.dump();  // no block merged (or stored) twice
  EXPECT_EQ(r.at("duplicates_different"), 0);
  if (r.at("duplicates_equal").get<uint64_t>() > 0) {
    EXPECT_NE(b.log().find("compared, identical"), std::string::npos) << b.log();
  }
}

TEST(Cluster, CoordinatorKilledMidPassResumesBitIdentical) {
  TempDir tmp;
  const json spec = disk_spec(200'000'000, 5);
  const json expected = local_bits(spec);
  TestCluster cl(tmp.path, {{"w1"}, {"w2"}});
  HttpClient& c = cl.c;
  const std::string id = submit(c, spec);
  auto rc = cl.redis.connect();
  wait_until([&] { return get_json(c, "/v1/jobs/" + id).at("samples").get<uint64_t>() > 50'000'000 &&
                          rc.cmd({"SCARD", "tally:active"}).as_int() > 0; },
             60, "the job mid-pass");
  cl.server.kill9();
  std::this_thread::sleep_for(300ms);
  cl.server.start();
  HttpClient c2 = cl.server.client();
  const json s = wait_state(c2, id, "succeeded", 120);
  EXPECT_EQ(s.at("bits"), expected);
}

TEST(Cluster, RedisRestartMidJobRepublishesAndUnreachableRedisPauses) {
  TempDir tmp;
  const json spec = disk_spec(200'000'000, 9);
  const json expected = local_bits(spec);
  TestCluster cl(tmp.path, {{"w1"}, {"w2"}});
  HttpClient& c = cl.c;
  const std::string id = submit(c, spec);
  wait_until([&] { return get_json(c, "/v1/jobs/" + id).at("samples").get<uint64_t>() > 50'000'000; }, 60,
             "the job under way");
  cl.redis.stop();
  // Unreachable: /readyz says why, the job is paused (not failed) and says so.
  wait_until([&] { return c.request("GET", "/readyz").status == 503; }, 10, "/readyz to fail");
  EXPECT_NE(c.request("GET", "/readyz").body.find("redis unreachable"), std::string::npos);
  wait_until([&] { return get_json(c, "/v1/jobs/" + id).value("waiting_reason", "").find("redis unreachable") !=
                          std::string::npos; },
             5, "the job's status to say it is paused");
  EXPECT_EQ(get_json(c, "/v1/jobs/" + id).at("state"), "running");
  std::this_thread::sleep_for(1s);
  cl.redis.start();  // empty: no streams, no groups, no results
  wait_until([&] { return c.request("GET", "/readyz").status == 200; }, 20, "/readyz to recover");
  const json s = wait_state(c, id, "succeeded", 120);
  EXPECT_EQ(s.at("bits"), expected);
  EXPECT_GE(metrics_counts(c).at("passes_republished").get<uint64_t>(), 1u);
}

TEST(Cluster, CancelAndExtendAcrossTheCluster) {
  TempDir tmp;
  TestCluster cl(tmp.path, {{"w1"}, {"w2"}});
  HttpClient& c = cl.c;

  // Cancel: the job stops within about one block and nothing of it stays in Redis.
  const std::string big = submit(c, disk_spec(50'000'000'000ULL, 3));
  wait_until([&] { return get_json(c, "/v1/jobs/" + big).at("samples").get<uint64_t>() > 0; }, 60, "progress");
  const int cancel_big = c.request("DELETE", "/v1/jobs/" + big).status;
  ASSERT_TRUE(cancel_big == 202 || cancel_big == 200) << cancel_big;  // 200: nothing was in flight
  const json cancelled = wait_state(c, big, "cancelled", 10);
  auto rc = cl.redis.connect();
  wait_until([&] { return rc.cmd({"KEYS", "tally:[sprfv]:" + big + ":*"}).elems.empty(); }, 5, "the job's keys to go");
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
  TestCluster cl(tmp.path, {});
  HttpClient& c = cl.c;
  const std::string id = submit(c, spec);
  std::this_thread::sleep_for(1500ms);
  const json waiting = get_json(c, "/v1/jobs/" + id);
  EXPECT_EQ(waiting.at("state"), "running");
  EXPECT_EQ(waiting.at("samples"), 0);
  EXPECT_NE(waiting.value("waiting_reason", "").find("waiting for a tally-worker"), std::string::npos) << waiting.dump();
  EXPECT_GT(waiting.at("blocks").at("pending").get<uint64_t>(), 0u) << waiting.dump();

  WorkerProcess first(cl.redis.url(), "first", tmp.path);
  wait_until([&] { return get_json(c, "/v1/jobs/" + id).at("samples").get<uint64_t>() > 20'000'000; }, 60,
             "progress with one worker");
  WorkerProcess late(cl.redis.url(), "late", tmp.path);  // joins a job in flight
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
  // These workers refuse what the server accepts (more than 2 dimensions): every
  // delivery of every block fails on every worker with the worker's error.
  TestCluster cl(tmp.path, {{"strict1", 1, {"--max-dimensions", "2"}}, {"strict2", 1, {"--max-dimensions", "2"}}},
                 {.server_flags = {"--max-deliveries", "4"}});
  HttpClient& c = cl.c;
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

  // The workers have no --asset-dir and their own cache: the file can only come through Redis.
  TestCluster cl(tmp.path, {{"w1", 1, {"--cache-dir", (tmp.path / "cache1").string()}}},
                 {.server_flags = {"--asset-dir", assets.string()}});
  HttpClient& c = cl.c;
  const std::string id = submit(c, spec);
  const json s = wait_state(c, id, "succeeded", 60);
  EXPECT_EQ(s.at("bits"), expected);
  auto rc = cl.redis.connect();
  const std::string sha = cluster::sha256_hex(obj);
  EXPECT_EQ(rc.cmd({"GET", "tally:asset:" + sha}).str, obj);  // content-addressed
  EXPECT_TRUE(fs::exists(tmp.path / "cache1" / "blobs" / sha));
}


// An 8-bit RGB PNG written with OpenImageIO.
std::string png_bytes(int w, int h, const std::vector<uint8_t>& rgb) {
  std::vector<unsigned char> buf;
  OIIO::Filesystem::IOVecOutput proxy(buf);
  auto out = OIIO::ImageOutput::create("t.png", &proxy);
  OIIO::ImageSpec spec(w, h, 3, OIIO::TypeDesc::UINT8);
  out->open("t.png", spec);
  out->write_image(OIIO::TypeDesc::UINT8, rgb.data());
  out->close();
  return {buf.begin(), buf.end()};
}

// Textures (issue 16): the files an OBJ and a glTF name themselves (.mtl + map_Kd; the
// glTF's external .bin and .png) are shipped by hash with the file the spec names.
TEST(Cluster, TexturesAndFilesNamedInsideSceneFilesReachWorkers) {
  TempDir tmp;
  const fs::path assets = tmp.path / "assets";
  fs::create_directories(assets / "m" / "tex");
  fs::create_directories(assets / "g");
  std::vector<uint8_t> px;
  for (int i = 0; i < 64; ++i) px.insert(px.end(), {uint8_t(i * 4), uint8_t(255 - i * 2), 100});
  std::ofstream(assets / "m" / "tex" / "ramp.png", std::ios::binary) << png_bytes(8, 8, px);
  std::ofstream(assets / "m" / "quad.obj") << "mtllib quad.mtl\nv -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\n"
                                           << "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nusemtl ramp\nf 1/1 2/2 3/3\nf 1/1 3/3 4/4\n";
  std::ofstream(assets / "m" / "quad.mtl") << "newmtl ramp\nKd 1 1 1\nmap_Kd -clamp on tex/ramp.png\n";
  test::GltfWriter g;
  g.doc["images"] = {{{"uri", "side.png"}}};
  g.doc["textures"] = {{{"source", 0}}};
  const int mat = g.material({{"pbrMetallicRoughness", {{"baseColorTexture", {{"index", 0}}}, {"metallicFactor", 0.0}}}});
  g.node({{"mesh", g.mesh({-1, -1, -0.5, 1, -1, -0.5, 1, 1, -0.5}, {0, 1, 2}, mat, {}, {0, 0, 1, 0, 1, 1})},
          {"translation", {1.5, 0, 0}}});
  g.save_gltf(assets / "g", "side");
  std::ofstream(assets / "g" / "side.png", std::ios::binary) << png_bytes(8, 8, px);
  const json spec = {
      {"kind", "lighting"}, {"seed", 4}, {"sampler", "sobol"},
      {"scene", {{"camera", {{"position", {0, 0, 2}}, {"look_at", {0, 0, 0}}, {"resolution", {8, 8}}}},
                 {"shapes", json::array({{{"type", "mesh"}, {"obj", "m/quad.obj"}}, {{"type", "gltf"}, {"file", "g/side.gltf"}}})},
                 {"lights", json::array({{{"type", "directional"}, {"direction", {0.2, 0.1, 1}}, {"irradiance", {3, 3, 3}}}})}}},
      {"query", {{"type", "image"}, {"max_depth", 2}, {"tile_size", 8}}},
      {"estimators", {"mis"}}, {"stop", {{"max_samples", 8}}}};
  JobLimits limits;
  limits.asset_dir = assets.string();
  const json expected = local_bits(spec, 0, limits);

  RedisServer redis(tmp.path);
  std::vector<std::string> flags = cluster_flags(redis);
  flags.insert(flags.end(), {"--asset-dir", assets.string()});
  ServerProcess server(tmp.path / "data", flags);
  WorkerProcess w1(redis.url(), "w1", tmp.path, 1, {"--cache-dir", (tmp.path / "cache1").string()});
  HttpClient c = server.client();
  wait_until([&] { return live_workers(c) == 1; }, 20, "a worker");
  const std::string id = submit(c, spec);
  const json s = wait_state(c, id, "succeeded", 60);
  EXPECT_EQ(s.at("bits"), expected);
  // Each named file is in the worker's job directory under the name the compiler asks for.
  size_t linked = 0;
  for (const auto& e : fs::recursive_directory_iterator(tmp.path / "cache1" / "jobs")) {
    const std::string name = e.path().filename().string();
    linked += name == "quad.mtl" || name == "ramp.png" || name == "side.bin" || name == "side.png";
  }
  EXPECT_EQ(linked, 4u);
}

// ---------------------------------------------------------------- guarantees that need
// injected faults: tally-test-worker (tests/cluster/fault_worker_main.cpp) wraps the
// kernel with slow, throwing or aborting blocks chosen by their first sample.

WorkerOptions faulty(const std::string& faults) { return {{}, {"TALLY_TEST_FAULT=" + faults}, true}; }

size_t count_in(const std::string& text, const std::string& needle) {
  size_t n = 0;
  for (size_t p = text.find(needle); p != std::string::npos; p = text.find(needle, p + 1)) ++n;
  return n;
}

// Every store outcome so far (first, equal or different duplicate, stale), from Redis.
uint64_t stores(cluster::RedisConn& rc) {
  const auto v = rc.cmd({"HMGET", "tally:counters", "first", "dup_equal", "dup_differ", "stale"});
  uint64_t n = 0;
  for (const auto& e : v.elems) n += static_cast<uint64_t>(e.to_int().value_or(0));
  return n;
}

TEST(Cluster, HeartbeatKeepsALongBlocksLease) {
  TempDir tmp;
  // Three passes (1, 2 and 4 blocks); the first block sleeps 3.5 s, 3.5 leases of 1 s.
  const json spec = disk_spec(7 * 4096, 21);
  const json expected = local_bits(spec);
  // Both run the same faults: whichever takes the long block sleeps, the other is idle
  // and would reclaim it (XAUTOCLAIM) the moment its lease lapsed.
  TestCluster cl(tmp.path, {{"a", 1, {}, faulty("sleep_at=0:3500")}, {"b", 1, {}, faulty("sleep_at=0:3500")}},
                 {.lease_s = 1.0});
  HttpClient& c = cl.c;
  WorkerProcess &a = cl.worker(0), &b = cl.worker(1);
  const std::string id = submit(c, spec);
  const json s = wait_state(c, id, "succeeded", 60);
  EXPECT_EQ(s.at("bits"), expected);
  // The long block was delivered once: one worker started it, nobody reclaimed it.
  const std::string logs = a.log() + b.log();
  EXPECT_EQ(count_in(logs, "test fault: block at sample 0 sleeps"), 1u) << logs;
  std::this_thread::sleep_for(1200ms);  // the counts are refreshed twice a second
  const json r = metrics_counts(c);
  EXPECT_EQ(r.at("duplicates_equal"), 0) << r.dump();
  EXPECT_EQ(r.at("stale"), 0) << r.dump();
  EXPECT_EQ(r.at("first"), r.at("blocks_merged")) << r.dump();
  EXPECT_EQ(r.at("blocks_merged"), 7) << r.dump();
}

TEST(Cluster, DifferingDuplicateFailsTheJobLoudly) {
  TempDir tmp;
  // Slow blocks (150 ms each) keep a pass open long enough to inject into it.
  TestCluster cl(tmp.path, {{"a", 1, {}, faulty("sleep_ms=150")}, {"b", 1, {}, faulty("sleep_ms=150")}});
  HttpClient& c = cl.c;
  const std::string id = submit(c, disk_spec(4096ull * 1023, 17));
  auto rc = cl.redis.connect();
  // An entry's results already stored in an open pass of at least 8 entries.
  std::string rest, slot, stored;  // rest = {id}:{run}:{pass}
  wait_until([&] {
    for (const auto& k : rc.cmd({"KEYS", "tally:r:" + id + ":*"}).elems) {
      const auto slots = rc.cmd({"HKEYS", k.str});
      const std::string pkey = "tally:p:" + k.str.substr(8);
      const long long e = rc.cmd({"HGET", pkey, "e"}).to_int().value_or(0);
      if (e >= 8 && !slots.elems.empty() && static_cast<long long>(slots.elems.size()) < e) {
        rest = k.str.substr(8);
        slot = slots.elems[0].str;
        stored = rc.cmd({"GET", "tally:v:" + rest + ":" + slot}).str;
        return !stored.empty();
      }
    }
    return false;
  }, 60, "a stored entry in an open pass");
  // The same blocks, one bit different: what a non-deterministic kernel would send.
  std::vector<BlockResult> results = cluster::decode_entry_results(stored);
  ASSERT_FALSE(results.empty());
  results.front().tallies.at(0).mean = std::bit_cast<double>(std::bit_cast<uint64_t>(results.front().tallies.at(0).mean) ^ 1u);
  std::string bytes;
  for (const BlockResult& res : results) cluster::append_entry_result(bytes, cluster::encode_result(res));
  ASSERT_NE(bytes, stored);
  // Store it as a worker would: upload, then the store script.
  const size_t c1 = rest.find(':'), c2 = rest.find(':', c1 + 1);
  const std::string run = rest.substr(c1 + 1, c2 - c1 - 1);
  const std::string e = rc.cmd({"HGET", "tally:p:" + rest, "e"}).str;
  const std::string upload = cluster::upload_key("test/0");
  rc.cmd({"SET", upload, bytes});
  const auto r = rc.cmd({"EVAL", cluster::kStoreScript, "9", "tally:r:" + rest, "tally:s:" + rest, "tally:job:" + id,
                         "tally:d:" + rest, "tally:counters", "tally:notify", "tally:p:" + rest, upload,
                         "tally:v:" + rest + ":" + slot, slot, "0-1", run, e, id, "0", std::to_string(results.size()),
                         cluster::result_digest(bytes)});
  ASSERT_EQ(r.elems.size(), 4u);
  EXPECT_EQ(r.elems[2].integer, static_cast<long long>(results.size())) << "the script did not see the difference";
  EXPECT_EQ(rc.cmd({"EXISTS", upload}).as_int(), 0) << "the upload outlived its store";
  const json s = wait_state(c, id, "failed", 30);
  const std::string msg = s.value("error_message", "");
  EXPECT_NE(msg.find("non-determinism"), std::string::npos) << msg;
  EXPECT_NE(msg.find("slot " + slot), std::string::npos) << msg;
  // The counts are refreshed twice a second: wait for the refresh after the failure.
  wait_until([&] { return metrics_counts(c).at("duplicates_different").get<uint64_t>() >= 1; }, 30,
             "duplicates_different to count the differing duplicate");
  // The failed job's keys are gone: no worker keeps computing it.
  wait_until([&] { return rc.cmd({"KEYS", "tally:[sprfv]:" + id + ":*"}).elems.empty(); }, 5, "the job's keys to go");
}

// The store script alone, against a real Redis: the results move from the upload key to
// the entry's value key (first wins), never through Lua; duplicates are compared byte
// for byte while the pass is open and by digest after; every path removes the upload.
TEST(Cluster, StoreScriptMovesUploadsFirstWinsAndComparesDuplicates) {
  TempDir tmp;
  RedisServer redis(tmp.path);
  auto rc = redis.connect();
  const std::string id = "j1", run = "1.1", rest = id + ":" + run + ":0";
  const std::string rk = "tally:r:" + rest, sk = "tally:s:" + rest, jk = "tally:job:" + id, dk = "tally:d:" + rest;
  const std::string pk = "tally:p:" + rest, vk = "tally:v:" + rest + ":0", up = cluster::upload_key("w/0");
  rc.cmd({"HSET", jk, "run", run, "cancelled", "0"});
  rc.cmd({"XGROUP", "CREATE", sk, "w", "$", "MKSTREAM"});
  const std::string entry = rc.cmd({"XADD", sk, "*", "b", "x", "s", "0"}).str;
  rc.cmd({"XREADGROUP", "GROUP", "w", "w/0", "COUNT", "1", "STREAMS", sk, ">"});
  const std::string a(300'000, 'a'), b = std::string(299'999, 'a') + "b";
  // entries in the pass = 2, so the first store does not complete it.
  auto store = [&](const std::string& bytes) {
    rc.cmd({"SET", up, bytes, "PX", cluster::kUploadTtlMs});
    const auto r = rc.cmd({"EVAL", cluster::kStoreScript, "9", rk, sk, jk, dk, "tally:counters", "tally:notify", pk, up,
                           vk, "0", entry, run, "2", id, "0.5", "4", cluster::result_digest(bytes)});
    EXPECT_EQ(rc.cmd({"EXISTS", up}).as_int(), 0) << "the upload outlived its store";
    std::vector<long long> out;
    for (const auto& e : r.elems) out.push_back(e.integer);
    return out;
  };
  EXPECT_EQ(store(a), (std::vector<long long>{4, 0, 0, 0}));
  EXPECT_EQ(rc.cmd({"GET", vk}).str, a);
  EXPECT_EQ(rc.cmd({"TTL", vk}).as_int(), -1) << "the value kept the upload's TTL";
  EXPECT_EQ(rc.cmd({"HGET", rk, "0"}).str, "1");
  EXPECT_EQ(rc.cmd({"HGET", pk, "done"}).as_int(), 4);
  EXPECT_EQ(rc.cmd({"XPENDING", sk, "w"}).elems.at(0).as_int(), 0) << "the entry was not acked";
  EXPECT_EQ(store(a), (std::vector<long long>{0, 4, 0, 0}));  // open pass: byte for byte
  EXPECT_EQ(store(b), (std::vector<long long>{0, 0, 4, 0}));
  EXPECT_EQ(rc.cmd({"GET", vk}).str, a) << "a duplicate replaced the first results";
  EXPECT_EQ(rc.cmd({"HGET", jk, "mismatch"}).str, "0");
  // Small results travel inline (the last argument): same outcomes, no upload involved.
  const std::string vk1 = "tally:v:" + rest + ":1", small = "small results", other = "other results";
  auto store_inline = [&](const std::string& bytes) {
    const auto r = rc.cmd({"EVAL", cluster::kStoreScript, "9", rk, sk, jk, dk, "tally:counters", "tally:notify", pk, up,
                           vk1, "1", entry, run, "2", id, "0.5", "4", cluster::result_digest(bytes), bytes});
    std::vector<long long> out;
    for (const auto& e : r.elems) out.push_back(e.integer);
    return out;
  };
  EXPECT_EQ(store_inline(small), (std::vector<long long>{4, 0, 0, 0}));
  EXPECT_EQ(rc.cmd({"GET", vk1}).str, small);
  EXPECT_EQ(rc.cmd({"HLEN", rk}).as_int(), 2);
  EXPECT_EQ(rc.cmd({"LPOP", "tally:notify"}).str, id) << "the pass's last entry did not announce it";
  EXPECT_EQ(store_inline(small), (std::vector<long long>{0, 4, 0, 0}));
  EXPECT_EQ(store_inline(other), (std::vector<long long>{0, 0, 4, 0}));
  EXPECT_EQ(rc.cmd({"GET", vk1}).str, small);
  // The pass merged (its keys gone, digests kept): duplicates compared by digest.
  rc.cmd({"DEL", sk, rk, pk, vk, vk1});
  EXPECT_EQ(store(a), (std::vector<long long>{0, 4, 0, 0}));
  EXPECT_EQ(store(b), (std::vector<long long>{0, 0, 4, 0}));
  EXPECT_EQ(rc.cmd({"EXISTS", vk}).as_int(), 0) << "a store after the merge left a value behind";
  // Cancelled: stale, nothing stored.
  rc.cmd({"HSET", jk, "cancelled", "1"});
  EXPECT_EQ(store(a), (std::vector<long long>{0, 0, 0, 4}));
  EXPECT_EQ(rc.cmd({"EXISTS", vk}).as_int(), 0);
  // No upload (Redis restarted between the two commands): an error the worker retries on.
  try {
    rc.cmd({"EVAL", cluster::kStoreScript, "9", rk, sk, jk, dk, "tally:counters", "tally:notify", pk, up, vk, "0", entry,
            run, "2", id, "0.5", "4", cluster::result_digest(a)});
    ADD_FAILURE() << "a store without an upload succeeded";
  } catch (const cluster::RedisReplyError& e) {
    EXPECT_TRUE(std::string_view(e.what()).starts_with(cluster::kUploadMissing)) << e.what();
  }
}

TEST(Cluster, CrashLoopFailsTheJobAfterNDeliveries) {
  TempDir tmp;
  // The first block kills whichever worker computes it (abort), on every delivery; a
  // supervisor (this loop, like Kubernetes or compose) restarts dead workers.
  TestCluster cl(tmp.path, {{"c1", 1, {}, faulty("abort_at=0")}, {"c2", 1, {}, faulty("abort_at=0")}},
                 {.lease_s = 1.0, .server_flags = {"--max-deliveries", "2"}});
  HttpClient& c = cl.c;
  auto& ws = cl.workers;
  const std::string id = submit(c, disk_spec(1'000'000, 19));
  int crashes = 0;
  json s;
  const auto deadline = std::chrono::steady_clock::now() + 60s;
  while (std::chrono::steady_clock::now() < deadline) {
    for (auto& w : ws) {
      if (w->exited()) {
        EXPECT_EQ(w->exit_code(), 128 + SIGABRT) << w->log();
        ++crashes;
        w->start();
      }
    }
    s = get_json(c, "/v1/jobs/" + id);
    if (s.at("state") != "running") break;
    std::this_thread::sleep_for(20ms);
  }
  ASSERT_EQ(s.at("state"), "failed") << s.dump();
  const std::string msg = s.value("error_message", "");
  EXPECT_NE(msg.find("no worker finished it"), std::string::npos) << msg;
  EXPECT_NE(msg.find("crash"), std::string::npos) << msg;
  // Delivered --max-deliveries + 2 times at most: the job never loops.
  std::this_thread::sleep_for(2500ms);  // more than two leases: nothing is delivered again
  for (auto& w : ws) crashes += w->exited() ? 1 : 0;
  size_t aborts = 0;
  for (auto& w : ws) aborts += count_in(w->log(), "aborts the worker");
  EXPECT_EQ(static_cast<size_t>(crashes), aborts);
  EXPECT_GE(crashes, 3) << msg;  // --max-deliveries + 1 deliveries without a result
  EXPECT_LE(crashes, 4) << msg;
  std::printf("crash loop: %d deliveries (all crashed) before the job failed: %s\n", crashes, msg.c_str());
}

TEST(Cluster, KernelThrowingFailsTheJobAfterNDeliveriesWithItsError) {
  TempDir tmp;
  TestCluster cl(tmp.path, {{"t1", 1, {}, faulty("throw_at=0")}, {"t2", 1, {}, faulty("throw_at=0")}},
                 {.server_flags = {"--max-deliveries", "3"}});
  HttpClient& c = cl.c;
  WorkerProcess &a = cl.worker(0), &b = cl.worker(1);
  const std::string id = submit(c, disk_spec(1'000'000, 23));
  const json s = wait_state(c, id, "failed", 30);
  const std::string msg = s.value("error_message", "");
  EXPECT_NE(msg.find("test fault: the kernel threw on the block at sample 0"), std::string::npos) << msg;
  EXPECT_NE(msg.find("failed on worker t"), std::string::npos) << msg;
  EXPECT_NE(msg.find("of job " + id), std::string::npos) << msg;
  // Exactly --max-deliveries deliveries, each counted once, then nothing more.
  std::this_thread::sleep_for(1s);
  EXPECT_EQ(count_in(a.log() + b.log(), "test fault: block at sample 0 throws"), 3u) << a.log() << b.log();
  EXPECT_EQ(metrics_counts(c).at("failed_deliveries"), 3);
  EXPECT_EQ(metrics_counts(c).at("blocks_merged"), 0);  // the other blocks of the pass are never merged
}

TEST(Cluster, DroppedConnectionsReconnectWithoutARedisRestartBitIdentical) {
  TempDir tmp;
  const json spec = disk_spec(160'000'000, 29);
  const json expected = local_bits(spec);
  TestCluster cl(tmp.path, {{"w1"}, {"w2"}});  // 30 s lease: no reclaim in this test
  HttpClient& c = cl.c;
  WorkerProcess &w1 = cl.worker(0), &w2 = cl.worker(1);
  const std::string id = submit(c, spec);
  auto rc = cl.redis.connect();
  const std::string before = rc.cmd({"INFO", "server"}).str;
  for (uint64_t at : {20'000'000ull, 60'000'000ull, 100'000'000ull}) {
    wait_until([&] { return get_json(c, "/v1/jobs/" + id).at("samples").get<uint64_t>() >= at; }, 60, "progress");
    // Every client but this one: the coordinator and all worker connections.
    const long long killed = rc.cmd({"CLIENT", "KILL", "TYPE", "normal"}).as_int();
    // The first time: the coordinator + 2 workers x (compute + heartbeat); later, whoever
    // has reconnected by then.
    EXPECT_GE(killed, at == 20'000'000ull ? 5 : 1);
  }
  const json s = wait_state(c, id, "succeeded", 90);
  EXPECT_EQ(s.at("bits"), expected);
  // Reconnected to the same Redis (no restart), so nothing was republished as lost.
  EXPECT_EQ(rc.run_id(), [&] { auto r2 = cl.redis.connect(); return r2.run_id(); }());
  const std::string logs = w1.log() + w2.log();
  // A worker reconnects either in its read loop ("connected to redis again") or while
  // storing a computed result ("reconnecting to store them", then the store succeeds:
  // the job's bits above prove nothing was lost).
  EXPECT_TRUE(logs.find("connected to redis again") != std::string::npos ||
              logs.find("reconnecting to store them") != std::string::npos)
      << logs;
  std::this_thread::sleep_for(1200ms);
  const json r = metrics_counts(c);
  EXPECT_EQ(r.at("first"), r.at("blocks_merged")) << r.dump();
  EXPECT_EQ(r.at("duplicates_different"), 0) << r.dump();
}

TEST(Cluster, AuthAndAclAgainstARealRedis) {
  TempDir tmp;
  const int port = free_loopback_port();
  // The default user needs "secret"; the ACL user tally has its own password.
  RedisServer redis(tmp.path, {"--requirepass", "secret", "--user", "tally", "on", ">pw", "~*", "&*", "+@all"},
                    "tally:pw", port);
  const json spec = disk_spec(20'000'000, 31);
  const json expected = local_bits(spec);
  const std::string tcp = fmt::format("redis://tally:pw@127.0.0.1:{}", port);
  const std::string sock = redis.socket();
  {
    // Refused credentials: a clear error at start and exit code 2, never a silent wait.
    WorkerProcess wrong("unix://tally:nope@" + sock, "wrong", tmp.path, 1);
    WorkerProcess none("unix://" + sock, "none", tmp.path, 1);
    wait_until([&] { return wrong.exited() && none.exited(); }, 15, "the refused workers to exit");
    EXPECT_EQ(wrong.exit_code(), 2) << wrong.log();
    EXPECT_NE(wrong.log().find("refused the credentials"), std::string::npos) << wrong.log();
    EXPECT_NE(wrong.log().find("WRONGPASS"), std::string::npos) << wrong.log();
    EXPECT_EQ(wrong.log().find("nope"), std::string::npos) << "the password is logged: " << wrong.log();
    EXPECT_EQ(none.exit_code(), 2) << none.log();
    EXPECT_NE(none.log().find("NOAUTH"), std::string::npos) << none.log();
    try {
      ServerProcess bad(tmp.path / "bad", {"--redis", fmt::format("redis://tally:nope@127.0.0.1:{}", port)});
      ADD_FAILURE() << "tally-server started with a wrong Redis password";
    } catch (const std::runtime_error& e) {
      const std::string what = e.what();
      EXPECT_NE(what.find("exited at start"), std::string::npos) << what;
      EXPECT_NE(what.find("refused the credentials"), std::string::npos) << what;
    }
  }
  // The coordinator over TCP as the ACL user; one worker as the ACL user on the socket,
  // one as the default user with requirepass's password.
  ServerProcess server(tmp.path / "data", {"--redis", tcp, "--checkpoint-interval", "0"});
  WorkerProcess acl(redis.url(), "acl", tmp.path, 1);
  WorkerProcess def("unix://secret@" + sock, "default", tmp.path, 1);
  HttpClient c = server.client();
  wait_until([&] { return live_workers(c) == 2; }, 20, "two authenticated workers");
  const std::string id = submit(c, spec);
  const json s = wait_state(c, id, "succeeded", 60);
  EXPECT_EQ(s.at("bits"), expected);
  EXPECT_EQ(server.log().find(":pw@"), std::string::npos) << "the password is logged";
}

TEST(Cluster, CancelStopsWithinAboutOneBlockPerThread) {
  TempDir tmp;
  // 2 workers x 2 threads, 250 ms blocks (one block per entry once measured).
  constexpr unsigned kThreads = 4;
  TestCluster cl(tmp.path, {{"a", 2, {}, faulty("sleep_ms=250")}, {"b", 2, {}, faulty("sleep_ms=250")}});
  HttpClient& c = cl.c;
  const std::string id = submit(c, disk_spec(4096ull * 4095, 37));
  auto rc = cl.redis.connect();
  // Mid-pass with every thread busy: passes of 1, 2, 4, 8 blocks are done, then 16.
  wait_until([&] { return get_json(c, "/v1/jobs/" + id).at("samples").get<uint64_t>() >= 15 * 4096; }, 60,
             "four passes");
  wait_until([&] { return get_json(c, "/v1/jobs/" + id).at("blocks").at("in_flight").get<uint64_t>() >= kThreads; },
             10, "every thread busy");
  const uint64_t at_cancel = stores(rc);
  const auto t0 = std::chrono::steady_clock::now();
  const int cancel = c.request("DELETE", "/v1/jobs/" + id).status;
  ASSERT_TRUE(cancel == 202 || cancel == 200) << cancel;  // 200: nothing was in flight
  wait_state(c, id, "cancelled", 10);
  // Quiet: no store for a whole block time (with a bound on the wait).
  uint64_t last = stores(rc);
  auto quiet_since = std::chrono::steady_clock::now();
  wait_until([&] {
    const uint64_t now = stores(rc);
    if (now != last) {
      last = now;
      quiet_since = std::chrono::steady_clock::now();
    }
    return std::chrono::steady_clock::now() - quiet_since > 600ms;
  }, 20, "the workers to go quiet");
  const double quiet_after = std::chrono::duration<double>(quiet_since - t0).count();
  const uint64_t after = last - at_cancel;
  std::printf("cancel: %llu blocks stored after DELETE (threads %u), the last %.3f s after it\n",
              static_cast<unsigned long long>(after), kThreads, quiet_after);
  // The blocks in flight finish (one per thread); a thread that finished just before the
  // cancel reached Redis may start one more. Never the rest of the pass.
  EXPECT_LE(after, 2 * kThreads);
  EXPECT_TRUE(rc.cmd({"KEYS", "tally:[sprfv]:" + id + ":*"}).elems.empty());
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

  TestCluster cl(tmp.path, {{"w1", 1, {"--cache-dir", (tmp.path / "cache1").string()}}});  // no --asset-dir
  HttpClient& c = cl.c;
  const std::string sha = cluster::sha256_hex(obj);
  ASSERT_EQ(c.request("PUT", "/v1/assets/sha256:" + sha, obj).status, 201);
  spec["scene"]["shapes"].back()["obj"] = "sha256:" + sha;
  const std::string id = submit(c, spec);
  const json s = wait_state(c, id, "succeeded", 60);
  EXPECT_EQ(s.at("bits"), expected);
  auto rc = cl.redis.connect();
  EXPECT_EQ(rc.cmd({"GET", "tally:asset:" + sha}).str, obj);
  EXPECT_TRUE(fs::exists(tmp.path / "cache1" / "blobs" / sha));  // the worker's store, checked against the hash
}

}  // namespace
// Large results (an image: a tally per pixel channel per block) are read by the
// coordinator while their pass runs, so the pass boundary reads only the last ones, and
// an image's pass is streamed (as a production frame's is: --checkpoint-copy-bytes 0
// here): each group merges into the state as soon as it and those before it are read.
// Those early reads and merges must change nothing: bits and every EXR pixel equal an
// in-process run, also when Redis restarts empty mid-job (results read or merged before
// the restart are kept, the pass is recomputed, nothing is merged twice).
TEST(Cluster, ImageResultsReadDuringThePassStayBitIdenticalThroughARedisRestart) {
  TempDir tmp;
  const json image = lighting_image_spec(256);  // 64 x 48: passes of up to 16 blocks
  const ImageReference expected = in_process_image(tmp.path, image);
  // Blocks of >= 40 ms (a sleep, no CPU): every pass lasts several of the coordinator's
  // 50 ms rounds, so results are there to be read before the pass ends.
  TestCluster cl(tmp.path, {{"w1", 1, {}, faulty("sleep_ms=40")}, {"w2", 1, {}, faulty("sleep_ms=40")}},
                 {.server_flags = {"--log-level", "debug", "--checkpoint-copy-bytes", "0"}});
  HttpClient& c = cl.c;
  const std::string id = submit(c, image);
  wait_until([&] { return get_json(c, "/v1/jobs/" + id).value("passes", 0) >= 2; }, 120, "two passes merged");
  cl.redis.stop();
  std::this_thread::sleep_for(500ms);
  cl.redis.start();  // empty
  json s;
  try {
    s = wait_state(c, id, "succeeded", 180);
  } catch (const std::exception& e) {
    FAIL() << e.what() << "\n" << cl.server.log();
  }
  EXPECT_EQ(s.at("bits"), expected.bits);
  EXPECT_EQ(exr_pixels(c, id, tmp.path), expected.pixels);
  EXPECT_GE(metrics_counts(c).at("passes_republished").get<uint64_t>(), 1u);
  // The coordinator's pass-boundary lines say how many results of each pass it had read
  // before the pass ended: at least one pass was read early.
  const std::string log = cl.server.log();
  size_t early = 0;
  for (size_t at = log.find("read before the end"); at != std::string::npos; at = log.find("read before the end", at + 1)) {
    const size_t comma = log.rfind(", ", at);
    if (comma != std::string::npos && std::stoul(log.substr(comma + 2, at - comma - 2)) > 0) ++early;
  }
  EXPECT_GE(early, 1u) << log;
  EXPECT_GT(metric(c, "tally_result_groups_streamed_total"), 0.0)
      << "the passes were not streamed";
}

}  // namespace tally::e2e
