// Worker pools (docs/cluster.md "Worker pools"): a job whose spec names a pool is
// computed only by workers started with --pool of that name; with no live worker in
// its pool it reads as queued and says which pool it waits for; an auth-file entry may
// restrict a principal to pools; in process the field is checked and changes nothing.
#include <gtest/gtest.h>

#include <fmt/format.h>

#include <fstream>
#include <regex>
#include <set>
#include <thread>

#include "cluster_process.hpp"
#include "cluster_test_support.hpp"
#include "server/cluster/assets.hpp"
#include "server_process.hpp"

namespace tally::e2e {
namespace {

json with_pool(json spec, const std::string& pool) {
  spec["pool"] = pool;
  return spec;
}

// The job ids whose entries a --verbose worker stored ("entry S of job ID pass P: ...").
std::set<std::string> jobs_in_log(const std::string& log) {
  std::set<std::string> ids;
  const std::regex line(R"(entry \d+ of job (\S+) pass \d+:)");
  for (auto it = std::sregex_iterator(log.begin(), log.end(), line); it != std::sregex_iterator(); ++it) {
    ids.insert((*it)[1].str());
  }
  return ids;
}

json worker_named(HttpClient& c, const std::string& name) {
  const json all = get_json(c, "/v1/workers");
  for (const json& w : all.at("workers")) {
    if (w.at("name") == name) return w;
  }
  return nullptr;
}

// Two workers in two pools, two jobs submitted together (either worker is free to take
// either job's entries unless the pools route them): each job is computed only by the
// worker of its pool, and its bits equal a run in one process.
TEST(ClusterPools, EachJobIsComputedOnlyByTheWorkersOfItsPool) {
  TempDir tmp;
  const json big = with_pool(disk_spec(60'000'000, 21), "big");
  const json small = with_pool(disk_spec(60'000'000, 22), "small");
  const json expected_big = local_bits(big), expected_small = local_bits(small);
  TestCluster cl(tmp.path, {{"wbig", 1, {"--pool", "big", "--verbose"}}, {"wsmall", 1, {"--pool", "small", "--verbose"}}});
  HttpClient& c = cl.c;

  // The registry shows each worker's pools and the live workers per pool.
  const json w = get_json(c, "/v1/workers");
  EXPECT_EQ(worker_named(c, "wbig").at("pools"), json::array({"big"})) << w.dump();
  EXPECT_EQ(worker_named(c, "wsmall").at("pools"), json::array({"small"})) << w.dump();
  EXPECT_EQ(w.at("pools"), (json{{"big", 1}, {"small", 1}})) << w.dump();
  const std::string metrics = c.request("GET", "/metrics").body;
  EXPECT_NE(metrics.find("tally_cluster_pool_workers{pool=\"big\"} 1\n"), std::string::npos) << metrics;
  EXPECT_NE(metrics.find("tally_cluster_pool_workers{pool=\"small\"} 1\n"), std::string::npos) << metrics;

  const std::string a = submit(c, big);
  const std::string b = submit(c, small);
  const json sa = wait_state(c, a, "succeeded", 120);
  const json sb = wait_state(c, b, "succeeded", 120);
  EXPECT_EQ(sa.at("bits"), expected_big);
  EXPECT_EQ(sb.at("bits"), expected_small);
  EXPECT_EQ(sa.at("spec").at("pool"), "big");

  // Every entry a worker stored is logged with its job: each worker stored entries of
  // its own pool's job and of no other.
  EXPECT_EQ(jobs_in_log(cl.worker(0).log()), std::set<std::string>{a}) << cl.worker(0).log();
  EXPECT_EQ(jobs_in_log(cl.worker(1).log()), std::set<std::string>{b}) << cl.worker(1).log();
  EXPECT_EQ(get_json(c, "/v1/workers").at("results").at("duplicates_different"), 0);
  // The pools' active sets are emptied as the passes are merged.
  auto rc = cl.redis.connect();
  EXPECT_EQ(rc.cmd({"SCARD", "tally:active:big"}).as_int(), 0);
  EXPECT_EQ(rc.cmd({"SCARD", "tally:active:small"}).as_int(), 0);
}

// A job whose pool no live worker serves reads as queued, its waiting reason names the
// pool, and the live worker of another pool computes none of it; a worker of its pool
// that joins later computes it, bit-identical to a run in one process.
TEST(ClusterPools, AJobWhosePoolHasNoLiveWorkerReadsAsQueuedNamingThePool) {
  TempDir tmp;
  const json spec = with_pool(disk_spec(40'000'000, 23), "gpu");
  const json expected = local_bits(spec);
  TestCluster cl(tmp.path, {{"wsmall", 1, {"--pool", "small", "--verbose"}}});
  HttpClient& c = cl.c;
  const std::string id = submit(c, spec);
  std::this_thread::sleep_for(1500ms);
  const json waiting = get_json(c, "/v1/jobs/" + id);
  EXPECT_EQ(waiting.at("state"), "queued") << waiting.dump();
  EXPECT_EQ(waiting.at("samples"), 0) << waiting.dump();
  EXPECT_EQ(waiting.value("waiting_reason", ""),
            "waiting for a tally-worker in pool \"gpu\": none of the live workers serves it")
      << waiting.dump();
  // The list agrees, and filters it as queued.
  const json queued = get_json(c, "/v1/jobs?state=queued");
  ASSERT_EQ(queued.at("jobs").size(), 1u) << queued.dump();
  EXPECT_EQ(queued.at("jobs").at(0).at("id"), id);
  EXPECT_TRUE(jobs_in_log(cl.worker(0).log()).empty()) << cl.worker(0).log();
  // A pool that jobs wait for and no worker serves is a gauge of 0, not a missing series.
  EXPECT_NE(c.request("GET", "/metrics").body.find("tally_cluster_pool_workers{pool=\"gpu\"} 0\n"), std::string::npos);

  WorkerProcess gpu(cl.redis.url(), "wgpu", tmp.path, 1, {"--pool", "gpu", "--pool", "big"});
  const json s = wait_state(c, id, "succeeded", 120);
  EXPECT_EQ(s.at("bits"), expected);
  EXPECT_FALSE(s.contains("waiting_reason"));
  EXPECT_TRUE(jobs_in_log(cl.worker(0).log()).empty()) << cl.worker(0).log();
  // The registry is read on the coordinator's refresh tick, which may come after a job
  // this short has ended: wait for it (bounded) before reading the worker's pools.
  json wgpu = worker_named(c, "wgpu");
  for (int i = 0; i < 250 && wgpu.is_null(); ++i) {
    std::this_thread::sleep_for(20ms);
    wgpu = worker_named(c, "wgpu");
  }
  ASSERT_FALSE(wgpu.is_null()) << get_json(c, "/v1/workers").dump();
  EXPECT_EQ(wgpu.at("pools"), json::array({"big", "gpu"}));
}

// A bad pool name is refused at submit with a 422 naming /pool; tally-worker refuses a
// bad --pool at start.
TEST(ClusterPools, BadPoolNamesAreRefusedNamingTheField) {
  TempDir tmp;
  TestCluster cl(tmp.path, {});
  HttpClient& c = cl.c;
  for (const json& bad : {json("has space"), json(""), json(std::string(65, 'p')), json(7)}) {
    json spec = disk_spec(1000);
    spec["pool"] = bad;
    const ClientResponse r = c.request("POST", "/v1/jobs", spec.dump(), {{"Content-Type", "application/json"}});
    EXPECT_EQ(r.status, 422) << bad.dump() << ": " << r.body;
    EXPECT_EQ(json::parse(r.body).value("pointer", ""), "/pool") << r.body;
  }
  WorkerProcess w(cl.redis.url(), "wbad", tmp.path, 1, {"--pool", "no/slash"});
  wait_until([&] { return w.exited(); }, 10, "tally-worker to refuse --pool no/slash");
  EXPECT_NE(w.exit_code(), 0);
  EXPECT_NE(w.log().find("--pool"), std::string::npos) << w.log();
}

struct Principal {
  std::string name, token;
  std::vector<std::string> pools;
};

void write_auth_file(const fs::path& path, const std::vector<Principal>& who) {
  json list = json::array();
  for (const auto& p : who) {
    json e = {{"name", p.name}, {"role", "user"}, {"token_sha256", cluster::sha256_hex(p.token)}};
    if (!p.pools.empty()) e["pools"] = p.pools;
    list.push_back(e);
  }
  std::ofstream(path) << json{{"principals", list}}.dump(2);
}

// An auth-file entry with "pools" restricts the principal to them: another pool, or
// none, is a 403 naming /pool (submit and validate); one of its pools is accepted. A
// principal without "pools" may name any. In process (no --redis) an accepted pool
// changes nothing: the bits equal those of the same spec without it.
TEST(ClusterPools, AnAuthFileEntryRestrictsAPrincipalToItsPools) {
  TempDir tmp;
  const Principal team{"team", std::string(43, 't'), {"big", "render"}};
  const Principal free{"free", std::string(43, 'f'), {}};
  write_auth_file(tmp.path / "auth.json", {team, free});
  ServerProcess server(tmp.path / "data", {"--auth-file", (tmp.path / "auth.json").string()});
  HttpClient as_team = server.client(ClientSecurity{team.token, ""});
  HttpClient as_free = server.client(ClientSecurity{free.token, ""});
  const HeaderList ct = {{"Content-Type", "application/json"}};
  const json spec = disk_spec(2'000'000, 24);
  for (const std::string route : {"/v1/jobs", "/v1/jobs/validate"}) {
    for (const json& s : {with_pool(spec, "small"), spec}) {
      const ClientResponse r = as_team.request("POST", route, s.dump(), ct);
      EXPECT_EQ(r.status, 403) << route << " " << s.dump() << ": " << r.body;
      const json p = json::parse(r.body);
      EXPECT_EQ(p.value("pointer", ""), "/pool") << r.body;
      EXPECT_NE(p.value("detail", "").find("\"big\", \"render\""), std::string::npos) << r.body;
    }
  }
  const std::string in_pool = submit(as_team, with_pool(spec, "render"));
  const std::string elsewhere = submit(as_free, with_pool(spec, "small"));
  const std::string plain = submit(as_free, spec);
  const json a = wait_state(as_team, in_pool, "succeeded");
  const json b = wait_state(as_free, elsewhere, "succeeded");
  const json d = wait_state(as_free, plain, "succeeded");
  EXPECT_EQ(a.at("bits"), d.at("bits"));
  EXPECT_EQ(b.at("bits"), d.at("bits"));
  EXPECT_EQ(d.at("bits"), local_bits(spec));
}

}  // namespace
}  // namespace tally::e2e
