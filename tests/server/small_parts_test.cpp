// Pieces with no state: JSON depth scan, router, listen address, cgroup quota,
// event log, problem bodies, SSE parser, URL parsing.
#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include "client/http_client.hpp"
#include "client/remote_commands.hpp"
#include "client/sse_parser.hpp"
#include "server/executor/cpu_quota.hpp"
#include "server/jobs/event_log.hpp"
#include "common/spec/json_depth.hpp"
#include "server/http/listen_address.hpp"
#include "server/http/problem.hpp"
#include "server/api/router.hpp"

namespace tally {
namespace {

TEST(JsonDepth, CountsOutsideStringsOnly) {
  EXPECT_EQ(json_nesting_depth("{}", 10), 1u);
  EXPECT_EQ(json_nesting_depth("[[1],[2,[3]]]", 10), 3u);
  EXPECT_EQ(json_nesting_depth("{\"a\":\"[[[[[\"}", 10), 1u);
  EXPECT_EQ(json_nesting_depth("{\"a\\\"[[[\":1}", 10), 1u);
  EXPECT_EQ(json_nesting_depth(std::string(100000, '['), 64), 65u);
  EXPECT_EQ(json_nesting_depth("3", 10), 0u);
}

TEST(Router, LiteralsWinAndParamsDecode) {
  Router r;
  int hit = 0;
  r.add("GET", "/v1/jobs/{id}", [&](const ApiRequest&, const PathParams&) { hit = 1; return HttpResponse{}; });
  r.add("POST", "/v1/jobs/validate", [&](const ApiRequest&, const PathParams&) { hit = 2; return HttpResponse{}; });
  auto m = r.match("GET", "/v1/jobs/a%20b");
  ASSERT_TRUE(m.route);
  EXPECT_EQ(m.params.at("id"), "a b");
  m = r.match("POST", "/v1/jobs/validate");
  ASSERT_TRUE(m.route);
  EXPECT_EQ(m.route->pattern, "/v1/jobs/validate");
  m = r.match("DELETE", "/v1/jobs/x");
  EXPECT_FALSE(m.route);
  EXPECT_EQ(m.allow, std::vector<std::string>{"GET"});
  EXPECT_FALSE(r.match("GET", "/v1/jobs/x/y").route);
  EXPECT_TRUE(r.match("GET", "/v1/jobs/x/y").allow.empty());
}

TEST(HttpRequest, QueryParameters) {
  HttpRequest r;
  r.target = "/v1/jobs?state=running&x=a%2Fb&flag";
  EXPECT_EQ(r.path(), "/v1/jobs");
  EXPECT_EQ(r.query_param("state"), "running");
  EXPECT_EQ(r.query_param("x"), "a/b");
  EXPECT_TRUE(r.has_query_param("flag"));
  EXPECT_FALSE(r.has_query_param("nope"));
}

TEST(ListenAddress, Parses) {
  auto a = parse_listen_address("127.0.0.1:8080");
  ASSERT_TRUE(a);
  EXPECT_EQ(a->host, "127.0.0.1");
  EXPECT_EQ(a->port, 8080);
  a = parse_listen_address("[::1]:0");
  ASSERT_TRUE(a);
  EXPECT_EQ(a->host, "::1");
  EXPECT_EQ(a->port, 0);
  EXPECT_EQ(parse_listen_address(":9000")->host, "127.0.0.1");
  EXPECT_FALSE(parse_listen_address("8080"));
  EXPECT_FALSE(parse_listen_address("host:99999"));
  EXPECT_FALSE(parse_listen_address("::1:80"));
}

TEST(CpuQuota, ParsesCgroupV2CpuMax) {
  EXPECT_DOUBLE_EQ(parse_cgroup_cpu_max("200000 100000\n").value(), 2.0);
  EXPECT_DOUBLE_EQ(parse_cgroup_cpu_max("150000 100000").value(), 1.5);
  EXPECT_FALSE(parse_cgroup_cpu_max("max 100000\n"));
  EXPECT_FALSE(parse_cgroup_cpu_max("garbage"));
  EXPECT_GE(default_worker_count(), 1u);
}

TEST(EventLog, ReplayGapAndWaiters) {
  EventLog log(3, 4);
  EXPECT_EQ(log.last_id(), 3 * EventLog::kEpochStride);
  int woken = 0;
  EXPECT_TRUE(log.wait(log.last_id(), [&] { ++woken; }));
  const uint64_t first = log.append("progress", "{}");
  EXPECT_EQ(woken, 1);
  for (int i = 0; i < 5; ++i) log.append("progress", "{}");
  auto r = log.read_after(first, 100);
  EXPECT_TRUE(r.gap);  // only 4 kept
  r = log.read_after(log.last_id() - 2, 100);
  EXPECT_FALSE(r.gap);
  EXPECT_EQ(r.events.size(), 2u);
  EXPECT_TRUE(log.read_after(5, 10).gap);                   // earlier epoch
  EXPECT_TRUE(log.read_after(log.last_id() + 1, 10).gap);   // future
  EXPECT_FALSE(log.wait(first, [] {}));                     // already has newer events
  EXPECT_TRUE(log.wait(log.last_id(), [&] { ++woken; }));
  log.close();
  EXPECT_EQ(woken, 2);
  EXPECT_TRUE(log.read_after(log.last_id(), 10).closed);
}

TEST(Problem, BodyHasRfc9457Fields) {
  const HttpResponse r = problem_response(422, "must be positive", "/stop/max_samples");
  EXPECT_EQ(r.status, 422);
  EXPECT_EQ(r.header("Content-Type"), "application/problem+json");
  const auto j = nlohmann::json::parse(r.body);
  EXPECT_EQ(j.at("type"), "https://tally.dev/problems/invalid-spec");
  EXPECT_EQ(j.at("title"), "Unprocessable Content");
  EXPECT_EQ(j.at("status"), 422);
  EXPECT_EQ(j.at("detail"), "must be positive");
  EXPECT_EQ(j.at("pointer"), "/stop/max_samples");
  EXPECT_FALSE(nlohmann::json::parse(problem_response(404, "x").body).contains("pointer"));
}

TEST(SseParser, SplitsEventsAcrossArbitraryPieces) {
  const std::string text =
      ": keep-alive\n\nid: 7\nevent: progress\ndata: {\"a\":1}\n\nid: 8\r\nevent: end\r\ndata: x\r\ndata: y\r\n\r\n";
  for (size_t piece : {1u, 2u, 5u, 1000u}) {
    std::vector<SseEvent> ev;
    SseParser p([&](const SseEvent& e) { ev.push_back(e); });
    for (size_t i = 0; i < text.size(); i += piece) p.feed(std::string_view(text).substr(i, piece));
    ASSERT_EQ(ev.size(), 2u) << piece;
    EXPECT_EQ(ev[0].id, "7");
    EXPECT_EQ(ev[0].event, "progress");
    EXPECT_EQ(ev[0].data, "{\"a\":1}");
    EXPECT_EQ(ev[1].event, "end");
    EXPECT_EQ(ev[1].data, "x\ny");
    EXPECT_EQ(p.last_event_id(), "8");
  }
}

TEST(HttpUrl, Parses) {
  auto u = parse_http_url("http://127.0.0.1:8080");
  ASSERT_TRUE(u);
  EXPECT_EQ(u->host, "127.0.0.1");
  EXPECT_EQ(u->port, "8080");
  u = parse_http_url("http://example.org/tally/");
  ASSERT_TRUE(u);
  EXPECT_EQ(u->port, "80");
  EXPECT_EQ(u->base_path, "/tally");
  EXPECT_FALSE(u->tls);
  u = parse_http_url("https://x");
  ASSERT_TRUE(u);
  EXPECT_TRUE(u->tls);
  EXPECT_EQ(u->port, "443");
  EXPECT_FALSE(parse_http_url("ftp://x"));
  EXPECT_FALSE(parse_http_url("127.0.0.1:8080"));
}

TEST(CliExitCodes, FromStatus) {
  using nlohmann::json;
  EXPECT_EQ(exit_code_for_status({{"state", "succeeded"}, {"stop_rule", {{"max_samples", 5}}}}), 0);
  EXPECT_EQ(exit_code_for_status({{"state", "succeeded"}, {"stop_rule", {{"rel_error", 0.1}}}, {"target_met", true}}), 0);
  EXPECT_EQ(exit_code_for_status({{"state", "succeeded"}, {"stop_rule", {{"rel_error", 0.1}}}, {"target_met", false}}), 2);
  EXPECT_EQ(exit_code_for_status({{"state", "failed"}}), 3);
  EXPECT_EQ(exit_code_for_status({{"state", "cancelled"}}), 3);
  EXPECT_EQ(exit_code_for_status({{"state", "running"}}), -1);
}

}  // namespace
}  // namespace tally
