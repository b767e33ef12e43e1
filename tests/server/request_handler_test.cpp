// Every route and every error status of the API, through the request handler
// alone (no sockets). Errors must be application/problem+json with type, title,
// status, detail (and pointer for spec errors).
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <set>

#include "client/sse_parser.hpp"
#include "server/http/event_stream.hpp"
#include "server_test_support.hpp"
#include "tests/support/response_body.hpp"

namespace tally::test {
namespace {

using nlohmann::json;

void expect_problem(const HttpResponse& r, int status) {
  EXPECT_EQ(r.status, status) << r.body;
  EXPECT_EQ(r.header("content-type"), "application/problem+json");
  const json p = json::parse(r.body);
  EXPECT_EQ(p.at("status"), status);
  EXPECT_TRUE(p.at("type").is_string());
  EXPECT_TRUE(p.at("title").is_string());
  EXPECT_FALSE(p.at("detail").get<std::string>().empty());
}

// Drains an event stream until it ends (bounded), as the session would.
std::vector<SseEvent> drain(EventStream& s, double seconds = 30) {
  std::vector<SseEvent> events;
  SseParser parser([&](const SseEvent& e) { events.push_back(e); });
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
  for (;;) {
    std::string out;
    const bool more = s.poll(out);
    parser.feed(out);
    if (!more) break;
    if (out.empty()) {
      std::atomic<bool> ready{false};
      s.on_ready([&] { ready = true; });
      if (!wait_until([&] { return ready.load(); }, 5)) ADD_FAILURE() << "stream stalled";
    }
    if (std::chrono::steady_clock::now() > deadline) {
      ADD_FAILURE() << "stream did not end";
      break;
    }
  }
  return events;
}

TEST(RequestHandler, HealthAndMetrics) {
  Harness h;
  EXPECT_EQ(h.call("GET", "/livez").status, 200);
  EXPECT_EQ(h.call("GET", "/readyz").status, 200);
  h.handler->set_ready(false);
  expect_problem(h.call("GET", "/readyz"), 503);
  const auto m = h.call("GET", "/metrics");
  EXPECT_EQ(m.status, 200);
  EXPECT_NE(m.body.find("tally_jobs{state=\"running\"}"), std::string::npos);
  EXPECT_NE(m.body.find("tally_http_requests_total{route=\"/readyz\",method=\"GET\",status=\"503\"} 1"),
            std::string::npos);
  EXPECT_NE(m.body.find("tally_http_request_duration_seconds_bucket{route=\"/livez\""), std::string::npos);
  EXPECT_NE(m.body.find("tally_queue_depth"), std::string::npos);
}

TEST(RequestHandler, SubmitGetListAndFinish) {
  Harness h;
  const auto r = h.call("POST", "/v1/jobs", fake_spec(20000).dump());
  ASSERT_EQ(r.status, 202) << r.body;
  const std::string id = json::parse(r.body).at("id");
  EXPECT_EQ(r.header("location"), "/v1/jobs/" + id);
  ASSERT_TRUE(h.wait_state(id, "succeeded"));
  const json s = h.call_json("GET", "/v1/jobs/" + id);
  EXPECT_EQ(s.at("samples"), 20000);
  EXPECT_EQ(s.at("stop_reason"), "max_samples");
  EXPECT_EQ(s.at("spec"), fake_spec(20000));
  EXPECT_TRUE(s.at("plan").is_object());
  EXPECT_TRUE(s.at("estimate").at("mean").is_number());
  EXPECT_TRUE(s.at("timing").at("started_at").is_string());
  EXPECT_TRUE(s.contains("samples_per_second"));
  EXPECT_TRUE(s.contains("eta_seconds"));
  EXPECT_EQ(s.at("bits").at("n"), 20000);
  const json list = h.call_json("GET", "/v1/jobs?state=succeeded");
  ASSERT_EQ(list.at("jobs").size(), 1u);
  EXPECT_EQ(list["jobs"][0]["id"], id);
  EXPECT_EQ(h.call_json("GET", "/v1/jobs?state=running").at("jobs").size(), 0u);
}

TEST(RequestHandler, MalformedRequestsAre400) {
  Harness h;
  expect_problem(h.call("POST", "/v1/jobs", "{\"kind\": "), 400);
  expect_problem(h.call("POST", "/v1/jobs", ""), 400);
  expect_problem(h.call("POST", "/v1/jobs", std::string(100000, '[')), 400);
  expect_problem(h.call("POST", "/v1/jobs/validate", std::string(100000, '{')), 400);
  expect_problem(h.call("POST", "/v1/jobs?priority=9", fake_spec(10).dump()), 400);
  expect_problem(h.call("GET", "/v1/jobs?state=done"), 400);
}

TEST(RequestHandler, DepthLimitIsConfigurable) {
  HandlerConfig hc;
  hc.max_json_depth = 3;
  Harness h(test_manager_config(), make_memory_store(), hc);
  json spec = fake_spec(10);  // depth 2: {"stop": {...}}
  EXPECT_EQ(h.call("POST", "/v1/jobs", spec.dump()).status, 202);
  expect_problem(h.call("POST", "/v1/jobs", "{\"a\":[[[1]]]}"), 400);
}

TEST(RequestHandler, NotFoundAndMethodNotAllowed) {
  Harness h;
  expect_problem(h.call("GET", "/v2/jobs"), 404);
  expect_problem(h.call("GET", "/v1/jobs/nope"), 404);
  expect_problem(h.call("DELETE", "/v1/jobs/nope"), 404);
  expect_problem(h.call("POST", "/v1/jobs/nope/extend", "{\"max_samples\": 5}"), 404);
  expect_problem(h.call("GET", "/v1/jobs/nope/events"), 404);
  expect_problem(h.call("GET", "/v1/jobs/nope/tiles/0"), 404);
  const auto r = h.call("PUT", "/v1/jobs");
  expect_problem(r, 405);
  EXPECT_EQ(r.header("allow"), "POST, GET");
  const auto r2 = h.call("PUT", "/v1/jobs/abc");
  expect_problem(r2, 405);
  EXPECT_EQ(r2.header("allow"), "GET, DELETE, PATCH");
  expect_problem(h.call("GET", "/v1/jobs/abc/extend"), 405);
}

TEST(RequestHandler, WrongContentTypeIs415) {
  Harness h;
  expect_problem(h.call("POST", "/v1/jobs", fake_spec(10).dump(), "text/plain"), 415);
  expect_problem(h.call("POST", "/v1/jobs", fake_spec(10).dump(), ""), 415);
  expect_problem(h.call("POST", "/v1/jobs/validate", fake_spec(10).dump(), "application/x-www-form-urlencoded"), 415);
  EXPECT_EQ(h.call("POST", "/v1/jobs", fake_spec(10).dump(), "application/json; charset=utf-8").status, 202);
}

TEST(RequestHandler, InvalidSpecIs422WithPointer) {
  Harness h;
  json spec = fake_spec(10);
  spec["colour"] = "blue";
  auto r = h.call("POST", "/v1/jobs", spec.dump());
  expect_problem(r, 422);
  EXPECT_EQ(json::parse(r.body).at("pointer"), "/colour");
  spec = fake_spec(10);
  spec["stop"]["max_samples"] = -3;
  r = h.call("POST", "/v1/jobs", spec.dump());
  expect_problem(r, 422);
  EXPECT_EQ(json::parse(r.body).at("pointer"), "/stop/max_samples");
  r = h.call("POST", "/v1/jobs", "[1,2]");
  expect_problem(r, 422);
  EXPECT_EQ(json::parse(r.body).at("pointer"), "");
  r = h.call("POST", "/v1/jobs/validate", "{\"kind\":\"fake\"}");
  expect_problem(r, 422);
  EXPECT_EQ(json::parse(r.body).at("pointer"), "/stop");
}

TEST(RequestHandler, PerJobCapsRefuseUpFront) {
  ManagerConfig mc = test_manager_config();
  mc.limits.max_samples = 1000;
  Harness h(mc);
  auto r = h.call("POST", "/v1/jobs", fake_spec(5000).dump());
  expect_problem(r, 422);
  EXPECT_EQ(json::parse(r.body).at("pointer"), "/stop/max_samples");
  EXPECT_EQ(h.call_json("GET", "/v1/jobs").at("jobs").size(), 0u);
}

TEST(RequestHandler, FullQueueIs503WithRetryAfter) {
  ManagerConfig mc = test_manager_config(1);
  mc.max_running = 1;
  mc.max_queued = 1;
  Harness h(mc);
  const std::string a = h.submit(fake_spec(kForever, 50));  // runs for ever
  const std::string b = h.submit(fake_spec(1000));              // queued
  EXPECT_EQ(h.state(b), "queued");
  const auto r = h.call("POST", "/v1/jobs", fake_spec(1000).dump());
  expect_problem(r, 503);
  EXPECT_EQ(r.header("retry-after"), "5");
  // Cancelling the queued job is immediate (200), the running one at a chunk boundary (202).
  EXPECT_EQ(h.call("DELETE", "/v1/jobs/" + b).status, 200);
  EXPECT_EQ(h.state(b), "cancelled");
  const auto c = h.call("DELETE", "/v1/jobs/" + a);
  EXPECT_TRUE(c.status == 202 || c.status == 200) << c.status;
  EXPECT_TRUE(h.wait_state(a, "cancelled", 10));
}

TEST(RequestHandler, CancelAndExtendConflictsAre409AndFinishedJobsAreDeleted) {
  Harness h;
  const std::string done = h.submit(fake_spec(5000));
  ASSERT_TRUE(h.wait_state(done, "succeeded"));
  expect_problem(h.call("POST", "/v1/jobs/" + done + "/extend", "{\"max_samples\": 5000}"), 409);  // already met
  // A finished job is deleted (issue 13; it was 409), then it is gone.
  EXPECT_EQ(h.call("DELETE", "/v1/jobs/" + done).status, 204);
  expect_problem(h.call("GET", "/v1/jobs/" + done), 404);
  expect_problem(h.call("POST", "/v1/jobs/" + done + "/extend", "{\"max_samples\": 9000}"), 404);
  const std::string running = h.submit(fake_spec(kForever, 50));
  expect_problem(h.call("POST", "/v1/jobs/" + running + "/extend", "{\"max_samples\": 10}"), 409);
  EXPECT_EQ(h.call("DELETE", "/v1/jobs/" + running).status / 100, 2);
  ASSERT_TRUE(h.wait_state(running, "cancelled", 10));
  EXPECT_EQ(h.call("DELETE", "/v1/jobs/" + running).status, 204);
  expect_problem(h.call("DELETE", "/v1/jobs/" + running), 404);
}

TEST(RequestHandler, ExtendBodyIsValidated) {
  Harness h;
  const std::string id = h.submit(fake_spec(5000));
  ASSERT_TRUE(h.wait_state(id, "succeeded"));
  auto r = h.call("POST", "/v1/jobs/" + id + "/extend", "{\"max_samples\": 10, \"speed\": 2}");
  expect_problem(r, 422);
  EXPECT_EQ(json::parse(r.body).at("pointer"), "/speed");
  r = h.call("POST", "/v1/jobs/" + id + "/extend", "{}");
  expect_problem(r, 422);
  r = h.call("POST", "/v1/jobs/" + id + "/extend", "{\"rel_error\": -1}");
  expect_problem(r, 422);
  EXPECT_EQ(json::parse(r.body).at("pointer"), "/rel_error");
  expect_problem(h.call("POST", "/v1/jobs/" + id + "/extend", "{\"max_samples\": 9000}", "text/plain"), 415);
}

TEST(RequestHandler, ExtendReopensAFinishedJob) {
  Harness h;
  const std::string id = h.submit(fake_spec(5000));
  ASSERT_TRUE(h.wait_state(id, "succeeded"));
  const auto r = h.call("POST", "/v1/jobs/" + id + "/extend", "{\"max_samples\": 30000}");
  ASSERT_EQ(r.status, 202) << r.body;
  ASSERT_TRUE(h.wait_state(id, "succeeded"));
  const json s = h.call_json("GET", "/v1/jobs/" + id);
  EXPECT_EQ(s.at("samples"), 30000);
  EXPECT_EQ(s.at("stop_rule").at("max_samples"), 30000);
  // Same bits as a job that asked for 30000 from the start.
  const std::string ref = h.submit(fake_spec(30000));
  ASSERT_TRUE(h.wait_state(ref, "succeeded"));
  // Pass sizes differ (5000 then more), so compare n and closeness rather than bits.
  const json rs = h.call_json("GET", "/v1/jobs/" + ref);
  EXPECT_EQ(rs.at("bits").at("n"), s.at("bits").at("n"));
  EXPECT_NEAR(rs.at("estimate").at("mean").get<double>(), s.at("estimate").at("mean").get<double>(), 1e-12);
}

TEST(RequestHandler, ValidateReturnsPlanPilotAndPrediction) {
  Harness h;
  json spec = fake_spec(1000000);
  spec["stop"] = {{"rel_error", 1e-3}};
  const auto r = h.call("POST", "/v1/jobs/validate", spec.dump());
  ASSERT_EQ(r.status, 200) << r.body;
  const json v = json::parse(r.body);
  EXPECT_TRUE(v.at("valid"));
  EXPECT_EQ(v.at("plan").at("kind"), "fake");
  EXPECT_GT(v.at("pilot").at("samples").get<double>(), 0);
  const json p = v.at("prediction");
  ASSERT_TRUE(p.is_object()) << v.dump();
  EXPECT_EQ(p.at("stops_by"), "error_target");
  // U(0,1): sigma^2 = 1/12, half-width 1e-3 * 0.5 at 95%: n = (1.96 sigma / 5e-4)^2 ~ 1.28e6.
  EXPECT_NEAR(p.at("samples").get<double>(), 1.28e6, 0.1e6);
  EXPECT_GT(p.at("seconds").get<double>(), 0);
  EXPECT_EQ(h.call_json("GET", "/v1/jobs").at("jobs").size(), 0u);  // a dry run
}

TEST(RequestHandler, EventStreamOfAFinishedJobIsSnapshotThenEnd) {
  Harness h;
  const std::string id = h.submit(fake_spec(20000));
  ASSERT_TRUE(h.wait_state(id, "succeeded"));
  const auto r = h.call("GET", "/v1/jobs/" + id + "/events");
  ASSERT_EQ(r.status, 200);
  EXPECT_EQ(r.header("content-type"), "text/event-stream");
  ASSERT_TRUE(r.stream);
  const auto ev = drain(*r.stream);
  ASSERT_EQ(ev.size(), 3u);
  EXPECT_EQ(ev[0].event, "state");
  EXPECT_EQ(ev[1].event, "progress");
  EXPECT_EQ(ev[2].event, "end");
  EXPECT_FALSE(ev[2].id.empty());
  EXPECT_EQ(json::parse(ev[1].data).at("samples"), 20000);
}

TEST(RequestHandler, EventStreamFollowsARunningJobAndResumes) {
  Harness h;
  const std::string id = h.submit(fake_spec(400000, 20));
  const auto r = h.call("GET", "/v1/jobs/" + id + "/events");
  ASSERT_TRUE(r.stream);
  const auto ev = drain(*r.stream);
  ASSERT_GE(ev.size(), 3u);
  EXPECT_EQ(ev.back().event, "end");
  uint64_t prev = 0, passes = 0;
  std::string mid_id;
  for (const auto& e : ev) {
    const uint64_t i = std::stoull(e.id);
    EXPECT_GE(i, prev);  // snapshot events share an id; live ones increase
    prev = i;
    if (e.event == "progress") {
      const json p = json::parse(e.data);
      EXPECT_GT(p.at("pass").get<uint64_t>(), passes);
      passes = p.at("pass");
      for (const char* k : {"samples", "estimate", "samples_per_second", "eta_seconds"}) EXPECT_TRUE(p.contains(k)) << k;
      if (mid_id.empty() && passes >= 2) mid_id = e.id;
    }
  }
  ASSERT_FALSE(mid_id.empty());
  // Resume after `mid_id`: only the later events, ending with `end`.
  const auto r2 = h.call("GET", "/v1/jobs/" + id + "/events", {}, "", {{"last-event-id", mid_id}});
  const auto ev2 = drain(*r2.stream);
  ASSERT_FALSE(ev2.empty());
  EXPECT_GT(std::stoull(ev2.front().id), std::stoull(mid_id));
  EXPECT_EQ(ev2.back().event, "end");
  // An id from an earlier epoch or the future: fresh snapshot.
  const auto r3 = h.call("GET", "/v1/jobs/" + id + "/events", {}, "", {{"last-event-id", "5"}});
  const auto ev3 = drain(*r3.stream);
  ASSERT_EQ(ev3.size(), 3u);
  EXPECT_EQ(ev3[0].event, "state");
  // Resuming at the end of a finished job repeats the end instead of hanging.
  const auto r4 = h.call("GET", "/v1/jobs/" + id + "/events", {}, "", {{"last-event-id", ev.back().id}});
  const auto ev4 = drain(*r4.stream);
  ASSERT_FALSE(ev4.empty());
  EXPECT_EQ(ev4.back().event, "end");
}

TEST(RequestHandler, EventStreamAsNdjson) {
  Harness h;
  const std::string id = h.submit(fake_spec(20000));
  ASSERT_TRUE(h.wait_state(id, "succeeded"));
  const auto r = h.call("GET", "/v1/jobs/" + id + "/events", {}, "", {{"accept", "application/x-ndjson"}});
  EXPECT_EQ(r.header("content-type"), "application/x-ndjson");
  std::string all;
  for (int i = 0; i < 10; ++i) {
    std::string out;
    const bool more = r.stream->poll(out);
    all += out;
    if (!more) break;
  }
  std::vector<SseEvent> ev;
  NdjsonParser p([&](const SseEvent& e) { ev.push_back(e); });
  p.feed(all);
  ASSERT_EQ(ev.size(), 3u);
  EXPECT_EQ(ev[2].event, "end");
  EXPECT_EQ(json::parse(ev[1].data).at("samples"), 20000);
}

TEST(RequestHandler, ImageJobsStreamTilesAndServeThem) {
  // The watcher must be attached before the image job runs: a watcher that arrives
  // after the end gets a snapshot (state, progress, end) and fetches every tile once.
  // So one running slot, a long job holding it, and the image job queued behind.
  ManagerConfig mc = test_manager_config();
  mc.max_running = 1;
  Harness h(mc);
  const std::string blocker = h.submit(fake_spec(kForever, 50));
  ASSERT_TRUE(h.wait_state(blocker, "running"));
  const std::string id = h.submit(fake_spec(8192, 0, 1, true));
  ASSERT_EQ(h.state(id), "queued");
  const auto r = h.call("GET", "/v1/jobs/" + id + "/events");
  ASSERT_TRUE(r.stream);
  EXPECT_EQ(h.call("DELETE", "/v1/jobs/" + blocker).status / 100, 2);
  const auto ev = drain(*r.stream);
  std::set<int> tiles;
  for (const auto& e : ev) {
    if (e.event != "tile") continue;
    const json t = json::parse(e.data);
    tiles.insert(t.at("tile").get<int>());
    EXPECT_EQ(t.at("w"), 4);
    EXPECT_TRUE(t.contains("pass"));
  }
  EXPECT_EQ(tiles.size(), 4u);
  ASSERT_TRUE(h.wait_state(id, "succeeded"));
  const json t = h.call_json("GET", "/v1/jobs/" + id + "/tiles/3");
  EXPECT_EQ(t.at("x"), 4);
  EXPECT_EQ(t.at("y"), 4);
  EXPECT_EQ(t.at("mean").size(), 48u);
  EXPECT_EQ(t.at("samples").size(), 16u);
  expect_problem(h.call("GET", "/v1/jobs/" + id + "/tiles/4"), 404);
  expect_problem(h.call("GET", "/v1/jobs/" + id + "/tiles/x"), 404);
  expect_problem(h.call("GET", "/v1/jobs/" + id + "/image.exr"), 501);  // no encoder in this harness
  const std::string scalar = h.submit(fake_spec(100));
  expect_problem(h.call("GET", "/v1/jobs/" + scalar + "/image.png"), 404);
  expect_problem(h.call("GET", "/v1/jobs/" + scalar + "/tiles/0"), 404);
}

TEST(RequestHandler, ImageEncodersAreUsedWhenPresent) {
  HandlerConfig hc;
  hc.images.png = [](const ImageSnapshot& s) { return "PNG" + std::to_string(s.width) + "x" + std::to_string(s.height); };
  hc.images.exr_file = [](const ImageSource& src, const JobState&, const json& meta, const std::filesystem::path& path) {
    std::ofstream(path, std::ios::binary) << "EXR" << src.width() << "x" << src.height() << meta.at("job_id").get<std::string>();
  };
  Harness h(test_manager_config(), make_memory_store(), hc);
  const std::string id = h.submit(fake_spec(8192, 0, 1, true));
  ASSERT_TRUE(h.wait_state(id, "succeeded"));
  const auto png = h.call("GET", "/v1/jobs/" + id + "/image.png");
  EXPECT_EQ(png.status, 200);
  EXPECT_EQ(png.header("content-type"), "image/png");
  EXPECT_EQ(png.body, "PNG8x8");
  // The EXR is written to a file and sent from it in parts; the file is gone once the
  // stream has it open.
  const auto exr = h.call("GET", "/v1/jobs/" + id + "/image.exr");
  EXPECT_EQ(exr.status, 200);
  EXPECT_EQ(exr.header("content-type"), "image/x-exr");
  ASSERT_TRUE(exr.stream);
  EXPECT_EQ(whole_body(exr), "EXR8x8" + id);
  for (const auto& f : std::filesystem::directory_iterator(std::filesystem::temp_directory_path())) {
    EXPECT_EQ(f.path().filename().string().find(id), std::string::npos) << f.path();
  }
}

TEST(RequestHandler, OpenApiDocumentMatchesTheRouteTable) {
  Harness h;
  const auto r = h.call("GET", "/v1/openapi.json");
  ASSERT_EQ(r.status, 200);
  const json doc = json::parse(r.body);
  EXPECT_EQ(doc.at("openapi"), "3.1.0");
  std::set<std::pair<std::string, std::string>> documented, routed;
  for (const auto& [path, ops] : doc.at("paths").items()) {
    for (const auto& [method, op] : ops.items()) {
      std::string m = method;
      for (char& c : m) c = static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
      documented.emplace(m, path);
      // Every documented error response is a problem.
      for (const auto& [code, resp] : op.at("responses").items()) {
        if (code[0] == '4' || code[0] == '5') {
          EXPECT_EQ(resp.at("$ref"), "#/components/responses/Problem") << path;
        }
      }
    }
  }
  for (const Route& rt : h.handler->router().routes()) routed.emplace(rt.method, rt.pattern);
  EXPECT_EQ(documented, routed);
}

TEST(RequestHandler, StatusIsCachedButFresh) {
  Harness h;
  const std::string id = h.submit(fake_spec(5000));
  ASSERT_TRUE(h.wait_state(id, "succeeded"));
  const auto a = h.call("GET", "/v1/jobs/" + id);
  const auto b = h.call("GET", "/v1/jobs/" + id);
  EXPECT_EQ(a.body, b.body);
  ASSERT_EQ(h.call("POST", "/v1/jobs/" + id + "/extend", "{\"max_samples\": 9000}").status, 202);
  ASSERT_TRUE(h.wait_state(id, "succeeded"));
  EXPECT_EQ(h.call_json("GET", "/v1/jobs/" + id).at("samples"), 9000);
}

}  // namespace
}  // namespace tally::test
