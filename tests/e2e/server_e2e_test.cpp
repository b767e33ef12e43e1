// The real server over real sockets: submit, stream, cancel, extend, resume with
// Last-Event-ID, every error status as problem+json, slow clients, depth bombs,
// SIGTERM and kill -9 durability (bit-identical resume), corrupt checkpoints,
// fairness, and the `tally` CLI.
#include <gtest/gtest.h>
#include <SQLiteCpp/SQLiteCpp.h>
#include <sys/wait.h>

#include <chrono>
#include <cstdio>
#include <fstream>
#include <sstream>
#include <exception>
#include <thread>

#include "client/sse_parser.hpp"
#include "server_process.hpp"

namespace tally::e2e {
namespace {

using nlohmann::json;
using clk = std::chrono::steady_clock;

double since(clk::time_point t0) { return std::chrono::duration<double>(clk::now() - t0).count(); }

void expect_problem(const ClientResponse& r, int status) {
  EXPECT_EQ(r.status, status) << r.body;
  EXPECT_EQ(r.header("Content-Type"), "application/problem+json") << status;
  const json p = json::parse(r.body);
  EXPECT_EQ(p.at("status"), status);
  EXPECT_TRUE(p.contains("type") && p.contains("title") && p.contains("detail"));
}

// Reads the SSE stream of a job; stops after `max_events` or at the end.
std::vector<SseEvent> read_events(HttpClient& c, const std::string& id, size_t max_events = 100000,
                                  const std::string& last_event_id = {}) {
  std::vector<SseEvent> ev;
  bool done = false;
  SseParser p([&](const SseEvent& e) {
    if (done) return;  // a chunk may carry more events than we want: drop the rest
    ev.push_back(e);
    if (e.event == "end" || e.event == "shutdown" || ev.size() >= max_events) done = true;
  });
  HeaderList h = {{"Accept", "text/event-stream"}};
  if (!last_event_id.empty()) h.emplace_back("Last-Event-ID", last_event_id);
  const ClientResponse r = c.stream("/v1/jobs/" + id + "/events", h,
                                    [&](std::string_view b) {
                                      p.feed(b);
                                      return !done;
                                    },
                                    60);
  EXPECT_EQ(r.status, 200);
  EXPECT_EQ(r.header("Content-Type"), "text/event-stream");
  return ev;
}

TEST(ServerE2E, SubmitStreamAndFinish) {
  TempDir tmp;
  ServerProcess server(tmp.path / "data");
  HttpClient c = server.client();
  const ClientResponse r = c.request("POST", "/v1/jobs", disk_spec(20'000'000).dump(), {{"Content-Type", "application/json"}});
  ASSERT_EQ(r.status, 202) << r.body;
  const std::string id = json::parse(r.body).at("id");
  EXPECT_EQ(r.header("Location"), "/v1/jobs/" + id);
  const auto ev = read_events(c, id);
  ASSERT_FALSE(ev.empty());
  EXPECT_EQ(ev.front().event, "state");
  EXPECT_EQ(ev.back().event, "end");
  int progress = 0;
  uint64_t prev = 0;
  for (const auto& e : ev) {
    ASSERT_FALSE(e.id.empty());
    EXPECT_GE(std::stoull(e.id), prev);
    prev = std::stoull(e.id);
    if (e.event == "progress") {
      ++progress;
      const json d = json::parse(e.data);
      for (const char* k : {"pass", "samples", "estimate", "samples_per_second", "eta_seconds"}) EXPECT_TRUE(d.contains(k));
    }
  }
  EXPECT_GE(progress, 1);
  const json s = get_json(c, "/v1/jobs/" + id);
  EXPECT_EQ(s.at("state"), "succeeded");
  EXPECT_EQ(s.at("samples"), 20'000'000);
  EXPECT_NEAR(s.at("estimate").at("mean").get<double>(), 3.14159265, 0.01);
  EXPECT_EQ(json::parse(ev.back().data).at("state"), "succeeded");
  // NDJSON variant of the same stream.
  std::string nd;
  c.stream("/v1/jobs/" + id + "/events", {{"Accept", "application/x-ndjson"}},
           [&](std::string_view b) {
             nd.append(b);
             return true;
           },
           30);
  std::vector<SseEvent> ndev;
  NdjsonParser np([&](const SseEvent& e) { ndev.push_back(e); });
  np.feed(nd);
  ASSERT_EQ(ndev.size(), 3u);
  EXPECT_EQ(ndev.back().event, "end");
}

TEST(ServerE2E, CancelRunningJob) {
  TempDir tmp;
  ServerProcess server(tmp.path / "data");
  HttpClient c = server.client();
  const std::string id = submit(c, disk_spec(50'000'000'000ULL));
  wait_state(c, id, "running");
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  const auto t0 = clk::now();
  const ClientResponse r = c.request("DELETE", "/v1/jobs/" + id);
  EXPECT_TRUE(r.status == 200 || r.status == 202) << r.body;
  const json s = wait_state(c, id, "cancelled", 10);
  EXPECT_LT(since(t0), 5.0);
  EXPECT_EQ(s.at("stop_reason"), "cancelled");
  const auto ev = read_events(c, id);
  EXPECT_EQ(ev.back().event, "end");
  // Finished: a second DELETE deletes it (issue 13), then it is gone.
  EXPECT_EQ(c.request("DELETE", "/v1/jobs/" + id).status, 204);
  expect_problem(c.request("GET", "/v1/jobs/" + id), 404);
  expect_problem(c.request("DELETE", "/v1/jobs/" + id), 404);
}

TEST(ServerE2E, ExtendFinishedJob) {
  TempDir tmp;
  ServerProcess server(tmp.path / "data");
  HttpClient c = server.client();
  const std::string id = submit(c, disk_spec(1'000'000));
  wait_state(c, id, "succeeded");
  const ClientResponse r = c.request("POST", "/v1/jobs/" + id + "/extend", R"({"max_samples": 4000000})",
                                     {{"Content-Type", "application/json"}});
  ASSERT_EQ(r.status, 202) << r.body;
  const json s = wait_state(c, id, "succeeded");
  EXPECT_EQ(s.at("samples"), 4'000'000);
  // An error target on top: runs until met.
  const ClientResponse r2 = c.request("POST", "/v1/jobs/" + id + "/extend", R"({"abs_error": 0.0005})",
                                      {{"Content-Type", "application/json"}});
  ASSERT_EQ(r2.status, 202) << r2.body;
  const json s2 = wait_state(c, id, "succeeded");
  EXPECT_TRUE(s2.at("target_met").get<bool>());
  EXPECT_LE(s2.at("error").at("abs").get<double>(), 0.0005);
  EXPECT_GT(s2.at("samples").get<uint64_t>(), 4'000'000u);
}

TEST(ServerE2E, ResumeStreamWithLastEventId) {
  TempDir tmp;
  ServerProcess server(tmp.path / "data", {"--event-buffer", "4096"});
  HttpClient c = server.client();
  const std::string id = submit(c, disk_spec(400'000'000));
  const auto first = read_events(c, id, 4);  // state, progress..., then hang up
  ASSERT_EQ(first.size(), 4u);
  const std::string last = first.back().id;
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  const auto rest = read_events(c, id, 100000, last);
  ASSERT_FALSE(rest.empty());
  EXPECT_GT(std::stoull(rest.front().id), std::stoull(last)) << "replayed events must follow Last-Event-ID";
  EXPECT_NE(rest.front().event, "state");  // not a snapshot: the missed events themselves
  EXPECT_EQ(rest.back().event, "end");
  // Passes are contiguous across the two connections.
  uint64_t last_pass = 0;
  for (const auto& e : first) {
    if (e.event == "progress") last_pass = json::parse(e.data).at("pass");
  }
  for (const auto& e : rest) {
    if (e.event != "progress") continue;
    EXPECT_EQ(json::parse(e.data).at("pass").get<uint64_t>(), last_pass + 1);
    last_pass += 1;
  }
  // An unknown (too old) id: a fresh snapshot.
  const auto snap = read_events(c, id, 100000, "12");
  ASSERT_GE(snap.size(), 2u);
  EXPECT_EQ(snap.front().event, "state");
  EXPECT_EQ(snap.back().event, "end");
}

TEST(ServerE2E, EveryErrorStatusIsProblemJson) {
  TempDir tmp;
  ServerProcess server(tmp.path / "data", {"--max-body", "4096", "--max-header", "2048", "--max-running", "1",
                                           "--max-queued", "0", "--max-samples", "100000000000"});
  HttpClient c = server.client();
  const HeaderList js = {{"Content-Type", "application/json"}};
  expect_problem(c.request("POST", "/v1/jobs", "{\"kind\":", js), 400);
  expect_problem(c.request("POST", "/v1/jobs", std::string(100000, '[').substr(0, 4000), js), 400);
  expect_problem(c.request("GET", "/v1/jobs/does-not-exist"), 404);
  expect_problem(c.request("GET", "/nowhere"), 404);
  const ClientResponse m = c.request("PUT", "/v1/jobs");
  expect_problem(m, 405);
  EXPECT_EQ(m.header("Allow"), "POST, GET");
  expect_problem(c.request("POST", "/v1/jobs", std::string(5000, ' '), js), 413);
  expect_problem(c.request("POST", "/v1/jobs", disk_spec(10).dump(), {{"Content-Type", "text/plain"}}), 415);
  json bad = disk_spec(1000);
  bad["estimator"]["type"] = "magic";
  const ClientResponse u = c.request("POST", "/v1/jobs", bad.dump(), js);
  expect_problem(u, 422);
  EXPECT_EQ(json::parse(u.body).at("pointer"), "/estimator/type");
  bad = disk_spec(1000);
  bad["surprise"] = true;
  expect_problem(c.request("POST", "/v1/jobs", bad.dump(), js), 422);
  expect_problem(c.request("GET", "/v1/jobs", {}, {{"X-Big", std::string(4000, 'x')}}), 431);
  // The one running slot is taken and nothing may queue: 503 with Retry-After.
  const std::string id = submit(c, disk_spec(50'000'000'000ULL));
  const ClientResponse full = c.request("POST", "/v1/jobs", disk_spec(1000).dump(), js);
  expect_problem(full, 503);
  EXPECT_FALSE(full.header("Retry-After").empty());
  expect_problem(c.request("POST", "/v1/jobs/" + id + "/extend", R"({"max_samples": 5})", js), 409);
  c.request("DELETE", "/v1/jobs/" + id);
  wait_state(c, id, "cancelled", 10);
  EXPECT_EQ(c.request("DELETE", "/v1/jobs/" + id).status, 204);  // finished: deleted
  expect_problem(c.request("DELETE", "/v1/jobs/" + id), 404);
  // Still alive and well.
  EXPECT_EQ(c.request("GET", "/livez").status, 200);
}

// --max-triangles caps the triangles of a lighting scene (all meshes together): a scene
// over it is a 422 naming the mesh's indices and the limit; one at the limit runs.
TEST(ServerE2E, MaxTrianglesFlagCapsLightingScenes) {
  TempDir tmp;
  ServerProcess server(tmp.path / "data", {"--max-triangles", "2"});
  HttpClient c = server.client();
  const auto spec_with = [](int triangles) {
    json idx = json::array();
    for (int t = 0; t < triangles; ++t) idx.insert(idx.end(), {0, 1, 2});
    const json mesh = {{"type", "mesh"}, {"vertices", {-1, -1, -1, 1, -1, -1, 0, 1, -1}}, {"indices", idx}, {"material", "white"}};
    const json lamp = {{"type", "quad"}, {"corner", {-0.5, -0.5, 2}}, {"edge_u", {0, 1, 0}}, {"edge_v", {1, 0, 0}}, {"material", "lamp"}};
    const json point = {{"p", {0, 0, 0}}, {"n", {0, 0, 1}}, {"wo", {0, 0, 1}}, {"material", "white"}};
    return json{{"kind", "lighting"},
                {"seed", 1},
                {"scene",
                 {{"materials",
                   {{"white", {{"type", "diffuse"}, {"albedo", {0.8, 0.8, 0.8}}}},
                    {"lamp", {{"type", "emissive"}, {"radiance", {5, 5, 5}}}}}},
                  {"shapes", json::array({mesh, lamp})}}},
                {"query", {{"type", "points"}, {"points", json::array({point})}}},
                {"estimators", {"light_area"}},
                {"stop", {{"max_samples", 1000}}}};
  };
  const ClientResponse over = c.request("POST", "/v1/jobs", spec_with(3).dump(), {{"Content-Type", "application/json"}});
  expect_problem(over, 422);
  const json p = json::parse(over.body);
  EXPECT_EQ(p.at("pointer"), "/scene/shapes/0/indices");
  EXPECT_NE(p.at("detail").get<std::string>().find("too many triangles (limit 2)"), std::string::npos) << over.body;
  const std::string id = submit(c, spec_with(2));
  EXPECT_EQ(wait_state(c, id, "succeeded", 30).at("state"), "succeeded");
}

TEST(ServerE2E, DepthBombOverTheWire) {
  TempDir tmp;
  ServerProcess server(tmp.path / "data");  // default body limit 1 MiB holds the bomb
  HttpClient c = server.client();
  const ClientResponse r =
      c.request("POST", "/v1/jobs", std::string(100000, '['), {{"Content-Type", "application/json"}});
  expect_problem(r, 400);
  const ClientResponse v =
      c.request("POST", "/v1/jobs/validate", std::string(100000, '{'), {{"Content-Type", "application/json"}});
  expect_problem(v, 400);
  EXPECT_EQ(c.request("GET", "/livez").status, 200);
}

TEST(ServerE2E, SlowClientsAreCutOff) {
  TempDir tmp;
  ServerProcess server(tmp.path / "data", {"--read-timeout", "1", "--idle-timeout", "1"});
  HttpClient c = server.client(20);
  // One byte every 0.25 s: the whole request would take ~10 s.
  const std::string req = "GET /livez HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: aaaaaaa\r\n\r\n";
  auto t0 = clk::now();
  const std::string answer = c.raw_exchange(req, 0.25);
  EXPECT_LT(since(t0), 8.0);
  EXPECT_EQ(answer.find("200 OK"), std::string::npos) << answer;
  EXPECT_EQ(answer.rfind("HTTP/1.1 408 Request Timeout", 0), 0u) << answer;  // told, not just cut off
  // A connection that never sends anything is closed after the idle timeout.
  t0 = clk::now();
  const std::string nothing = c.raw_exchange("");
  EXPECT_TRUE(nothing.empty());
  EXPECT_LT(since(t0), 5.0);
  // Malformed request line: 400 problem.
  const std::string bad = c.raw_exchange("GARBAGE\r\n\r\n");
  EXPECT_NE(bad.find("400"), std::string::npos) << bad;
  EXPECT_EQ(c.request("GET", "/livez").status, 200);
  const std::string metrics = c.request("GET", "/metrics").body;
  EXPECT_NE(metrics.find("tally_http_timeouts_total"), std::string::npos);
}

// The exact result bits of `spec` run to completion on a fresh server (the reference
// an interrupted-and-resumed run must reproduce).
std::string uninterrupted_bits(const std::filesystem::path& dir, const json& spec) {
  ServerProcess ref(dir);
  HttpClient c = ref.client();
  std::string bits = wait_state(c, submit(c, spec), "succeeded").at("bits").dump();
  EXPECT_EQ(ref.terminate(), 0);
  return bits;
}

TEST(ServerE2E, SigtermEndsStreamsAndJobsResumeBitIdentical) {
  TempDir tmp;
  // Long enough (~5 s on two idle cores) that SIGTERM always lands mid-job.
  const json spec = disk_spec(2'000'000'000, 11);
  const std::string expected = uninterrupted_bits(tmp.path / "ref", spec);
  ServerProcess server(tmp.path / "data", {"--checkpoint-interval", "0"});
  HttpClient c = server.client();
  const std::string id = submit(c, spec);
  std::vector<SseEvent> ev;
  std::exception_ptr watch_error;
  std::thread watcher([&] {
    try {
      HttpClient wc = server.client();
      ev = read_events(wc, id);
    } catch (...) {
      watch_error = std::current_exception();  // reported below, never std::terminate
    }
  });
  // Terminate once the job is really running and the watcher's stream is open (bounded
  // waits), not after a fixed delay: on a loaded machine the watcher could otherwise
  // connect after SIGTERM and be refused.
  auto stream_open = [&] {
    const std::string m = c.request("GET", "/metrics").body;
    const size_t at = m.find("\ntally_http_event_streams ");
    return at != std::string::npos && m.compare(at + 26, 2, "0\n") != 0;
  };
  for (int i = 0; i < 1500; ++i) {
    const json st = get_json(c, "/v1/jobs/" + id);
    if (st.at("state") == "running" && st.value("samples", 0ULL) > 0 && stream_open()) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  ASSERT_EQ(get_json(c, "/v1/jobs/" + id).at("state"), "running");
  EXPECT_TRUE(stream_open()) << "the watcher's event stream never opened";
  EXPECT_EQ(server.terminate(), 0) << server.log();
  watcher.join();
  ASSERT_FALSE(watch_error) << "the watcher failed";
  ASSERT_FALSE(ev.empty());
  EXPECT_EQ(ev.back().event, "shutdown");
  server.start();
  HttpClient c2 = server.client();
  const json s = wait_state(c2, id, "succeeded");
  EXPECT_EQ(s.at("bits").dump(), expected);
  EXPECT_EQ(server.terminate(), 0);
}

TEST(ServerE2E, KillDashNineAtSeveralPointsResumesBitIdentical) {
  TempDir tmp;
  // ~4 s on two idle cores, so every kill below lands mid-job.
  const json spec = disk_spec(1'500'000'000, 3);
  const std::string expected = uninterrupted_bits(tmp.path / "ref", spec);
  ServerProcess server(tmp.path / "data", {"--checkpoint-interval", "0"});
  HttpClient c = server.client();
  const std::string id = submit(c, spec);
  uint64_t last_samples = 0;
  for (int delay_ms : {150, 400, 700, 250}) {
    std::this_thread::sleep_for(std::chrono::milliseconds(delay_ms));
    server.kill9();
    server.start();
    HttpClient rc = server.client();
    const json s = get_json(rc, "/v1/jobs/" + id);
    if (s.at("state") == "succeeded") break;
    EXPECT_GE(s.value("samples", 0ULL), last_samples) << "progress must never go backwards";
    last_samples = s.value("samples", 0ULL);
  }
  HttpClient fc = server.client();
  const json s = wait_state(fc, id, "succeeded");
  EXPECT_EQ(s.at("bits").dump(), expected);
  EXPECT_EQ(s.at("samples"), 1'500'000'000);
}

TEST(ServerE2E, CorruptCheckpointIsReported) {
  TempDir tmp;
  ServerProcess server(tmp.path / "data", {"--checkpoint-interval", "0"});
  HttpClient c = server.client();
  const std::string victim = submit(c, disk_spec(50'000'000'000ULL, 1));
  const std::string done = submit(c, disk_spec(1'000'000, 2));
  wait_state(c, done, "succeeded");
  const auto t0 = clk::now();
  while (get_json(c, "/v1/jobs/" + victim).value("passes", 0) < 3 && since(t0) < 60) {
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  server.kill9();
  {
    SQLite::Database db((tmp.path / "data" / "tally.db").string(), SQLite::OPEN_READWRITE);
    // Checkpoints are stored in pieces (table checkpoint_pieces): truncate the first.
    SQLite::Statement u(db, "UPDATE checkpoint_pieces SET bytes = substr(bytes, 1, 40) WHERE id = ? AND n = 0");
    u.bind(1, victim);
    ASSERT_EQ(u.exec(), 1);
  }
  server.start();
  HttpClient c2 = server.client();
  const json s = get_json(c2, "/v1/jobs/" + victim);
  EXPECT_EQ(s.at("state"), "failed");
  EXPECT_NE(s.at("error_message").get<std::string>().find("checkpoint"), std::string::npos);
  EXPECT_EQ(get_json(c2, "/v1/jobs/" + done).at("state"), "succeeded");  // the rest is served
  EXPECT_EQ(c2.request("GET", "/readyz").status, 200);
}

TEST(ServerE2E, ShortJobBehindLongOneFinishesPromptly) {
  TempDir tmp;
  ServerProcess server(tmp.path / "data");
  HttpClient c = server.client();
  const std::string long_id = submit(c, disk_spec(50'000'000'000ULL));
  wait_state(c, long_id, "running");
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  const auto t0 = clk::now();
  const std::string short_id = submit(c, disk_spec(20'000'000));
  wait_state(c, short_id, "succeeded", 60);
  const double took = since(t0);
  EXPECT_EQ(get_json(c, "/v1/jobs/" + long_id).at("state"), "running");
  // 2e7 samples take ~0.3 s alone on 2 cores; with a fair share < 2 s, FIFO minutes.
  EXPECT_LT(took, 10.0);
  RecordProperty("short_job_seconds", std::to_string(took));
  c.request("DELETE", "/v1/jobs/" + long_id);
}

TEST(ServerE2E, ValidateMetricsAndOpenApiOverTheWire) {
  TempDir tmp;
  ServerProcess server(tmp.path / "data");
  HttpClient c = server.client();
  json spec = disk_spec(1000);
  spec["stop"] = {{"rel_error", 1e-4}};
  const ClientResponse v = c.request("POST", "/v1/jobs/validate", spec.dump(), {{"Content-Type", "application/json"}});
  ASSERT_EQ(v.status, 200) << v.body;
  const json vj = json::parse(v.body);
  EXPECT_TRUE(vj.at("prediction").at("samples").get<double>() > 1e6);
  EXPECT_EQ(vj.at("prediction").at("stops_by"), "error_target");
  const ClientResponse m = c.request("GET", "/metrics");
  EXPECT_EQ(m.status, 200);
  EXPECT_NE(m.body.find("tally_http_requests_total{route=\"/v1/jobs/validate\",method=\"POST\",status=\"200\"} 1"),
            std::string::npos);
  const json api = get_json(c, "/v1/openapi.json");
  EXPECT_EQ(api.at("openapi"), "3.1.0");
  EXPECT_EQ(c.request("GET", "/readyz").status, 200);
}

// A spec that names no estimator runs plain Monte Carlo; validate names the estimator
// the automatic choice would take when it is cheaper (issue 30), and that estimator
// really is: the job with it reaches the target with fewer evaluations than the
// suggestion says plain Monte Carlo needs.
TEST(ServerE2E, ValidateNamesAFasterEstimatorForASmoothIntegrand) {
  TempDir tmp;
  ServerProcess server(tmp.path / "data");
  HttpClient c = server.client();
  json spec = {{"kind", "integrate"},
               {"seed", 5},
               {"integrand", {{"expression", "exp(-x*x)"}}},
               {"domain", {{"type", "box"}, {"lower", {0}}, {"upper", {1}}}},
               {"stop", {{"rel_error", 1e-5}}}};
  const auto validate = [&](const json& s) {
    const ClientResponse v = c.request("POST", "/v1/jobs/validate", s.dump(), {{"Content-Type", "application/json"}});
    EXPECT_EQ(v.status, 200) << v.body;
    return json::parse(v.body);
  };
  const json v = validate(spec);
  ASSERT_TRUE(v.contains("suggestion")) << v.dump();
  const json& s = v.at("suggestion");
  EXPECT_EQ(s.at("estimator"), (json{{"type", "auto"}}));
  EXPECT_NE(s.at("would_choose").at("estimator"), "uniform");
  EXPECT_GT(s.at("fewer_evaluations").get<double>(), 100.0);
  EXPECT_NEAR(s.at("fewer_evaluations").get<double>(),
              s.at("default_predicted_evaluations").get<double>() / s.at("predicted_evaluations").get<double>(), 1e-6);
  EXPECT_LT(s.at("predicted_seconds").get<double>(), v.at("prediction").at("seconds").get<double>());

  json faster = spec;
  faster["estimator"] = s.at("estimator");
  EXPECT_FALSE(validate(faster).contains("suggestion")) << "a spec that names its estimator gets none";
  const std::string id = submit(c, faster);
  const json done = wait_state(c, id, "succeeded", 60);
  EXPECT_EQ(done.at("stop_reason"), "error_target");
  EXPECT_LT(done.at("result").at("evaluations").get<double>(), s.at("default_predicted_evaluations").get<double>() / 100)
      << done.dump();
  // erf(1) sqrt(pi) / 2, within 4 of its reported standard errors (and the target).
  const double mean = done.at("estimate").at("mean").get<double>();
  EXPECT_NEAR(mean, 0.7468241328124270, 4 * done.at("estimate").at("std_error").get<double>() + 1e-12);

}

// ---- the CLI

struct CliResult {
  int code = -1;
  std::string out;
};

CliResult run_cli(const std::string& args, const std::string& server_url) {
  const std::string cmd = "TALLY_SERVER=" + server_url + " NO_COLOR=1 " + std::string(TALLY_CLI_BIN) + " " + args +
                          " 2>&1";
  CliResult r;
  FILE* p = ::popen(cmd.c_str(), "r");
  if (!p) return r;
  char buf[4096];
  size_t n;
  while ((n = std::fread(buf, 1, sizeof buf, p)) > 0) r.out.append(buf, n);
  const int st = ::pclose(p);
  r.code = WIFEXITED(st) ? WEXITSTATUS(st) : -1;
  return r;
}

// Sizes on the command line are read as sizes (16MiB, bytes): a value that is not one
// stops the server at start (exit 2) naming the flag, before it listens. "-5" once read
// as 2^64 - 5 (every checkpoint copied, no pass streamed).
TEST(ServerE2E, CheckpointCopyBytesFlagRefusesWhatIsNotASize) {
  for (const std::string bad : {"-5", "x", "1e99", "16 MiB!"}) {
    const std::string cmd = std::string(TALLY_SERVER_BIN) + " --listen 127.0.0.1:0 --data-dir /nonexistent/never " +
                            "--checkpoint-copy-bytes '" + bad + "' 2>&1";
    FILE* p = ::popen(cmd.c_str(), "r");
    ASSERT_NE(p, nullptr);
    std::string out;
    char buf[4096];
    size_t n;
    while ((n = std::fread(buf, 1, sizeof buf, p)) > 0) out.append(buf, n);
    const int st = ::pclose(p);
    EXPECT_TRUE(WIFEXITED(st) && WEXITSTATUS(st) == 2) << bad << ": " << out;
    EXPECT_NE(out.find("--checkpoint-copy-bytes " + bad + " is not a size"), std::string::npos) << out;
  }
}

// The job id `tally submit` prints on stdout; run_cli merges stderr, where submit first
// prints the server's prediction ("tally: predicted: ...").
std::string submitted_id(const std::string& out) {
  std::istringstream in(out);
  for (std::string line; std::getline(in, line);) {
    if (line.rfind("tally: ", 0) != 0) return line;
  }
  return {};
}

TEST(ServerE2E, CliSubmitWatchGetListCancelExtend) {
  if (std::string(TALLY_CLI_BIN).empty()) GTEST_SKIP() << "the tally CLI is not built";
  TempDir tmp;
  ServerProcess server(tmp.path / "data");
  const std::string url = "http://127.0.0.1:" + std::to_string(server.port());
  const auto spec_file = tmp.path / "job.json";
  std::ofstream(spec_file) << disk_spec(5'000'000).dump();
  CliResult r = run_cli("submit " + spec_file.string() + " --watch", url);
  EXPECT_EQ(r.code, 0) << r.out;
  EXPECT_NE(r.out.find("succeeded"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("±"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("tally: predicted: stops by max_samples"), std::string::npos) << r.out;
  const std::string id = submitted_id(r.out);
  r = run_cli("get " + id + " --json", url);
  EXPECT_EQ(r.code, 0);
  EXPECT_EQ(json::parse(r.out).at("id"), id);
  r = run_cli("list", url);
  EXPECT_EQ(r.code, 0);
  EXPECT_NE(r.out.find(id), std::string::npos);
  // The same spec again is answered from the result cache: the list names the source.
  r = run_cli("submit " + spec_file.string(), url);
  ASSERT_EQ(r.code, 0) << r.out;
  const std::string cached = submitted_id(r.out);
  r = run_cli("list", url);
  EXPECT_EQ(r.code, 0);
  EXPECT_NE(r.out.find("cached from " + id), std::string::npos) << r.out;
  EXPECT_NE(r.out.find(cached), std::string::npos) << r.out;
  r = run_cli("cancel " + id, url);
  EXPECT_EQ(r.code, 4) << r.out;  // already finished: not sent (DELETE would delete it)
  EXPECT_EQ(run_cli("delete " + id + "x", url).code, 4);  // unknown job
  r = run_cli("extend " + id + " --max-samples 8000000", url);
  EXPECT_EQ(r.code, 0) << r.out;
  r = run_cli("watch " + id, url);
  EXPECT_EQ(r.code, 0) << r.out;
  // A target the samples cannot reach: exit 2.
  json tight = disk_spec(100'000);
  tight["stop"]["abs_error"] = 1e-6;
  std::ofstream(tmp.path / "tight.json") << tight.dump();
  r = run_cli("submit " + (tmp.path / "tight.json").string() + " --watch", url);
  EXPECT_EQ(r.code, 2) << r.out;
  // Cancelled: exit 3.
  std::ofstream(tmp.path / "long.json") << disk_spec(50'000'000'000ULL).dump();
  r = run_cli("submit " + (tmp.path / "long.json").string(), url);
  ASSERT_EQ(r.code, 0) << r.out;
  const std::string long_id = submitted_id(r.out);
  EXPECT_EQ(run_cli("cancel " + long_id, url).code, 0);
  EXPECT_EQ(run_cli("watch " + long_id, url).code, 3);
  // Invalid spec: 4; unknown job: 4; no server: 5.
  std::ofstream(tmp.path / "bad.json") << R"({"kind":"integrate"})";
  EXPECT_EQ(run_cli("submit " + (tmp.path / "bad.json").string(), url).code, 4);
  EXPECT_EQ(run_cli("get nope", url).code, 4);
  EXPECT_EQ(run_cli("list", "http://127.0.0.1:1").code, 5);
  EXPECT_EQ(run_cli("extend " + id, url).code, 4);  // no target given
  // delete: a running job is refused, a finished one deleted, then unknown.
  EXPECT_EQ(run_cli("delete " + long_id, url).code, 0);  // cancelled above: finished
  EXPECT_EQ(run_cli("get " + long_id, url).code, 4);
  EXPECT_EQ(run_cli("delete " + long_id, url).code, 4);
}

}  // namespace
}  // namespace tally::e2e
