// Access control without sockets: tokens and their hashes, the auth file's errors,
// the token bucket, the authorize step (401/403/429 with problem+json), tenancy on
// every job route, quotas, revocation of streams, browser sessions, the Host
// allowlist and Origin check, /metrics access, and the store's owner migration.
#include <SQLiteCpp/SQLiteCpp.h>
#include <gtest/gtest.h>

#include <unistd.h>

#include <atomic>
#include <chrono>
#include <filesystem>

#include "common/spec/spec_reader.hpp"
#include "server/auth/access_control.hpp"
#include "server/auth/auth_file.hpp"
#include "server/auth/token.hpp"
#include "server/auth/login_limiter.hpp"
#include "server/auth/token_bucket.hpp"
#include "server/http/event_stream.hpp"
#include "server_test_support.hpp"

namespace tally::test {
namespace {

using nlohmann::json;

TEST(Token, FreshTokensAreRandom256BitAndOnlyTheirHashIsKept) {
  const std::string a = generate_token(), b = generate_token();
  EXPECT_EQ(a.size(), 4u + 43u);  // "tly_" + 32 bytes in unpadded base64url
  EXPECT_EQ(a.substr(0, 4), "tly_");
  EXPECT_NE(a, b);
  EXPECT_TRUE(is_b64token(a));
  // FIPS 180-2 test vector.
  EXPECT_EQ(token_sha256_hex("abc"), "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
  EXPECT_TRUE(constant_time_equal("abcd", "abcd"));
  EXPECT_FALSE(constant_time_equal("abcd", "abce"));
  EXPECT_FALSE(constant_time_equal("abc", "abcd"));
  EXPECT_FALSE(is_b64token("a b"));
  EXPECT_FALSE(is_b64token(""));
  EXPECT_FALSE(is_b64token("=abc"));
}

std::string pointer_of_error(const json& j) {
  try {
    parse_auth_file(j);
  } catch (const SpecError& e) {
    return e.pointer();
  }
  return "(no error)";
}

TEST(AuthFile, ErrorsNameTheField) {
  const std::string h(64, 'a');
  EXPECT_EQ(pointer_of_error(json::object()), "/principals");
  EXPECT_EQ(pointer_of_error({{"principals", {{{"name", "x"}, {"role", "root"}, {"token_sha256", h}}}}}),
            "/principals/0/role");
  EXPECT_EQ(pointer_of_error({{"principals", {{{"name", "x"}, {"role", "user"}, {"token_sha256", "abc"}}}}}),
            "/principals/0/token_sha256");
  EXPECT_EQ(pointer_of_error({{"principals", {{{"name", "x"}, {"role", "user"}, {"token_sha256", h},
                                               {"quotas", {{"max_jobz", 1}}}}}}}),
            "/principals/0/quotas/max_jobz");
  EXPECT_EQ(pointer_of_error({{"principals", {{{"name", "x"}, {"role", "user"}, {"token_sha256", h}},
                                              {{"name", "x"}, {"role", "user"}, {"token_sha256", std::string(64, 'b')}}}}}),
            "/principals/1/name");
  const AuthFile f = parse_auth_file({{"principals", {{{"name", "x"}, {"role", "reader"}, {"token_sha256", h},
                                                        {"quotas", {{"max_running_jobs", 2}, {"requests_per_second", 5}}}}}}});
  ASSERT_EQ(f.principals.size(), 1u);
  EXPECT_EQ(f.principals[0].role, Role::reader);
  EXPECT_EQ(f.principals[0].quotas.max_running_jobs, 2u);
  EXPECT_EQ(f.principals[0].quotas.burst, 10.0);  // default burst: 2 s worth
}

// "pools" restricts a principal to worker pools: a non-empty list of distinct valid names.
TEST(AuthFile, PoolsAreANonEmptyListOfDistinctPoolNames) {
  const std::string h(64, 'a');
  auto with_pools = [&](json pools) {
    return json{{"principals", {{{"name", "x"}, {"role", "user"}, {"token_sha256", h}, {"pools", std::move(pools)}}}}};
  };
  EXPECT_EQ(pointer_of_error(with_pools(json::array())), "/principals/0/pools");
  EXPECT_EQ(pointer_of_error(with_pools("big")), "/principals/0/pools");
  EXPECT_EQ(pointer_of_error(with_pools({"big", "no space"})), "/principals/0/pools/1");
  EXPECT_EQ(pointer_of_error(with_pools({"big", 3})), "/principals/0/pools/1");
  EXPECT_EQ(pointer_of_error(with_pools({"big", "big"})), "/principals/0/pools/1");
  const AuthFile f = parse_auth_file(with_pools({"big", "render"}));
  EXPECT_EQ(f.principals.at(0).pools, (std::vector<std::string>{"big", "render"}));
  EXPECT_EQ(principal_entry_json(f.principals.at(0)).at("pools"), json({"big", "render"}));
  EXPECT_TRUE(parse_auth_file({{"principals", {{{"name", "y"}, {"role", "user"}, {"token_sha256", h}}}}})
                  .principals.at(0).pools.empty());
}

TEST(TokenBucket, RateAndBurstExactly) {
  TokenBucket b(2.0, 3.0, 100.0);
  EXPECT_EQ(b.take(100.0), 0.0);
  EXPECT_EQ(b.take(100.0), 0.0);
  EXPECT_EQ(b.take(100.0), 0.0);
  EXPECT_DOUBLE_EQ(b.take(100.0), 0.5);   // empty: one token every 0.5 s
  EXPECT_DOUBLE_EQ(b.take(100.25), 0.25);
  EXPECT_EQ(b.take(100.5), 0.0);
  EXPECT_EQ(b.take(200.0), 0.0);  // refilled to the burst, not beyond
  EXPECT_EQ(b.take(200.0), 0.0);
  EXPECT_EQ(b.take(200.0), 0.0);
  EXPECT_GT(b.take(200.0), 0.0);
}

// Principals: admin, two users (alice, bob), a reader (rita), a scraper (prom).
struct Principals {
  std::string admin = generate_token(), alice = generate_token(), bob = generate_token(), rita = generate_token(),
              prom = generate_token();
  Quotas alice_quotas;
  AuthFile file(bool with_alice = true) const {
    AuthFile f;
    auto add = [&](std::string name, Role role, const std::string& token, Quotas q = {}) {
      f.principals.push_back(PrincipalEntry{std::move(name), role, token_sha256_hex(token), q, {}});
    };
    add("root", Role::admin, admin);
    if (with_alice) add("alice", Role::user, alice, alice_quotas);
    add("bob", Role::user, bob);
    add("rita", Role::reader, rita);
    add("prom", Role::metrics, prom);
    return f;
  }
};

HttpRequest::Headers bearer(const std::string& token) { return {{"authorization", "Bearer " + token}}; }

struct AuthHarness {
  explicit AuthHarness(const Principals& p, ManagerConfig mc = test_manager_config(), bool metrics_open = true)
      : access(p.file()), h(mc, make_memory_store(), config(metrics_open)) {}
  HandlerConfig config(bool metrics_open) {
    HandlerConfig hc;
    hc.access.access = &access;
    hc.access.metrics_open = metrics_open;
    return hc;
  }
  HttpResponse as(const std::string& token, std::string method, std::string target, std::string body = {}) {
    return h.call(std::move(method), std::move(target), std::move(body), "application/json", bearer(token));
  }
  std::string submit_as(const std::string& token, const json& spec) {
    auto r = as(token, "POST", "/v1/jobs", spec.dump());
    if (r.status != 202) throw std::runtime_error("submit: " + r.body);
    return json::parse(r.body).at("id").get<std::string>();
  }
  std::string state(const std::string& token, const std::string& id) {
    return json::parse(as(token, "GET", "/v1/jobs/" + id).body).at("state");
  }
  AccessControl access;
  Harness h;
};

void expect_problem(const HttpResponse& r, int status, const std::string& what) {
  EXPECT_EQ(r.status, status) << what << ": " << r.body;
  EXPECT_EQ(r.header("Content-Type"), "application/problem+json") << what;
  const json p = json::parse(r.body);
  EXPECT_EQ(p.at("status"), status) << what;
  EXPECT_EQ(r.header("X-Content-Type-Options"), "nosniff") << what;
}

TEST(Authorize, MissingMalformedAndUnknownTokensAre401WithBearerChallenge) {
  Principals p;
  AuthHarness a(p);
  const std::string unknown = generate_token();
  struct Case {
    HttpRequest::Headers headers;
    std::string challenge;
  };
  const std::vector<Case> cases = {
      {{}, "Bearer realm=\"tally\""},
      {{{"authorization", "Basic YWxpY2U6c2VjcmV0"}}, "Bearer realm=\"tally\", error=\"invalid_request\""},
      {{{"authorization", "Bearer"}}, "Bearer realm=\"tally\", error=\"invalid_request\""},
      {{{"authorization", "Bearer a b"}}, "Bearer realm=\"tally\", error=\"invalid_request\""},
      {bearer(unknown), "Bearer realm=\"tally\", error=\"invalid_token\""},
  };
  for (const auto& c : cases) {
    for (const auto& [method, target] : std::vector<std::pair<std::string, std::string>>{
             {"GET", "/v1/jobs"}, {"POST", "/v1/jobs"}, {"GET", "/v1/jobs/abc"}, {"GET", "/v1/openapi.json"}}) {
      const HttpResponse r = a.h.call(method, target, "{}", "application/json", c.headers);
      expect_problem(r, 401, method + " " + target);
      EXPECT_EQ(r.header("WWW-Authenticate"), c.challenge);
      EXPECT_EQ(r.body.find(unknown), std::string::npos) << "a token never appears in an error body";
    }
  }
  // Open routes stay open.
  EXPECT_EQ(a.h.call("GET", "/livez").status, 200);
  EXPECT_EQ(a.h.call("GET", "/readyz").status, 200);
}

TEST(Tenancy, OthersJobsAre404OnEveryRouteAndMissingFromTheList) {
  Principals p;
  AuthHarness a(p);
  const std::string id = a.submit_as(p.alice, fake_spec(kForever, 1, 1, true));  // an image job
  ASSERT_TRUE(wait_until([&] { return a.state(p.alice, id) == "running"; }));
  const std::vector<std::pair<std::string, std::string>> job_routes = {
      {"GET", "/v1/jobs/" + id},           {"DELETE", "/v1/jobs/" + id}, {"PATCH", "/v1/jobs/" + id},
      {"POST", "/v1/jobs/" + id + "/extend"}, {"GET", "/v1/jobs/" + id + "/events"},
      {"GET", "/v1/jobs/" + id + "/tiles/0"}, {"GET", "/v1/jobs/" + id + "/image.exr"},
      {"GET", "/v1/jobs/" + id + "/image.png"}};
  for (const auto& [m, t] : job_routes) {
    const HttpResponse r = a.as(p.bob, m, t, R"({"max_samples": 10})");
    expect_problem(r, 404, "bob: " + m + " " + t);
    EXPECT_EQ(json::parse(r.body).at("detail"), "no job with id \"" + id + "\"") << "same answer as a missing job";
  }
  // The reader sees only its own jobs too.
  expect_problem(a.as(p.rita, "GET", "/v1/jobs/" + id), 404, "rita");
  auto ids_seen_by = [&](const std::string& token) {
    std::vector<std::string> ids;
    const json list = json::parse(a.as(token, "GET", "/v1/jobs").body);
    for (const auto& j : list.at("jobs")) ids.push_back(j.at("id"));
    return ids;
  };
  EXPECT_TRUE(ids_seen_by(p.bob).empty());
  EXPECT_TRUE(ids_seen_by(p.rita).empty());
  EXPECT_EQ(ids_seen_by(p.alice), std::vector<std::string>{id});
  EXPECT_EQ(ids_seen_by(p.admin), std::vector<std::string>{id});
  EXPECT_EQ(a.as(p.alice, "GET", "/v1/jobs/" + id + "/tiles/0").status, 200);
  const json st = json::parse(a.as(p.admin, "GET", "/v1/jobs/" + id).body);
  EXPECT_EQ(st.at("owner"), "alice");
  // Its owner and an admin may change its priority (200 with the summary).
  const HttpResponse by_alice = a.as(p.alice, "PATCH", "/v1/jobs/" + id, R"({"priority": 2})");
  EXPECT_EQ(by_alice.status, 200) << by_alice.body;
  EXPECT_EQ(json::parse(by_alice.body).at("priority"), 2);
  const HttpResponse by_admin = a.as(p.admin, "PATCH", "/v1/jobs/" + id, R"({"priority": -1})");
  EXPECT_EQ(by_admin.status, 200) << by_admin.body;
  EXPECT_EQ(json::parse(a.as(p.alice, "GET", "/v1/jobs/" + id).body).at("priority"), -1);
  // The admin may act on anyone's job (200: cancelled at once, 202: at the next chunk boundary).
  const int cancelled = a.as(p.admin, "DELETE", "/v1/jobs/" + id).status;
  EXPECT_TRUE(cancelled == 200 || cancelled == 202) << cancelled;
  ASSERT_TRUE(wait_until([&] { return a.state(p.alice, id) == "cancelled"; }));
}

TEST(Tenancy, ReaderIsReadOnlyOnItsOwnJobs) {
  Principals p;
  AuthHarness a(p);
  Submitter rita;
  rita.owner = "rita";  // a job rita submitted when she was a user
  const std::string id = a.h.manager->submit(fake_spec(kForever, 1, 1, true), 0, rita)->id();
  ASSERT_TRUE(wait_until([&] { return a.state(p.rita, id) == "running"; }));
  EXPECT_EQ(a.as(p.rita, "GET", "/v1/jobs/" + id).status, 200);
  EXPECT_EQ(a.as(p.rita, "GET", "/v1/jobs/" + id + "/tiles/0").status, 200);
  EXPECT_EQ(json::parse(a.as(p.rita, "GET", "/v1/jobs").body).at("jobs").size(), 1u);
  for (const auto& [m, t] : std::vector<std::pair<std::string, std::string>>{{"DELETE", "/v1/jobs/" + id},
                                                                           {"PATCH", "/v1/jobs/" + id},
                                                                           {"POST", "/v1/jobs/" + id + "/extend"},
                                                                           {"POST", "/v1/jobs"},
                                                                           {"POST", "/v1/jobs/validate"}}) {
    const HttpResponse r = a.as(p.rita, m, t, fake_spec(10).dump());
    expect_problem(r, 403, "rita: " + m + " " + t);
    EXPECT_EQ(json::parse(r.body).at("detail"), "role reader is read-only");
  }
  // The metrics role has no business with jobs.
  expect_problem(a.as(p.prom, "GET", "/v1/jobs"), 403, "prom");
  a.h.call("DELETE", "/v1/jobs/" + id, {}, "", bearer(p.admin));
}

TEST(Quotas, RunningAndQueuedJobsPerPrincipal) {
  Principals p;
  p.alice_quotas.max_running_jobs = 1;
  p.alice_quotas.max_queued_jobs = 1;
  AuthHarness a(p, test_manager_config(1));
  const std::string first = a.submit_as(p.alice, fake_spec(kForever, 1));
  ASSERT_TRUE(wait_until([&] { return a.state(p.alice, first) == "running"; }));
  const std::string second = a.submit_as(p.alice, fake_spec(kForever, 1));
  std::this_thread::sleep_for(std::chrono::milliseconds(100));
  EXPECT_EQ(a.state(p.alice, second), "queued") << "the server has free slots; alice's quota holds it back";
  const HttpResponse third = a.as(p.alice, "POST", "/v1/jobs", fake_spec(kForever, 1).dump());
  expect_problem(third, 403, "third job");
  EXPECT_NE(json::parse(third.body).at("detail").get<std::string>().find("max_queued_jobs"), std::string::npos);
  // Bob's quota is his own.
  const std::string bobs = a.submit_as(p.bob, fake_spec(kForever, 1));
  ASSERT_TRUE(wait_until([&] { return a.state(p.bob, bobs) == "running"; }));
  // A slot frees: the queued job runs.
  const int cancel = a.as(p.alice, "DELETE", "/v1/jobs/" + first).status;
  EXPECT_TRUE(cancel == 202 || cancel == 200) << cancel;  // 200: cancelled at once, between passes
  EXPECT_TRUE(wait_until([&] { return a.state(p.alice, second) == "running"; }));
  a.as(p.alice, "DELETE", "/v1/jobs/" + second);
  a.as(p.bob, "DELETE", "/v1/jobs/" + bobs);
}

TEST(Quotas, PerJobCapsAreTighterThanTheServers) {
  Principals p;
  p.alice_quotas.max_samples = 1000;
  AuthHarness a(p);
  const HttpResponse r = a.as(p.alice, "POST", "/v1/jobs", fake_spec(5000).dump());
  expect_problem(r, 422, "over alice's max_samples");
  EXPECT_EQ(json::parse(r.body).at("pointer"), "/stop/max_samples");
  EXPECT_NE(r.body.find("1000"), std::string::npos) << r.body;
  EXPECT_EQ(a.as(p.bob, "POST", "/v1/jobs", fake_spec(5000).dump()).status, 202) << "bob has the server's caps";
  EXPECT_EQ(a.as(p.alice, "POST", "/v1/jobs", fake_spec(1000).dump()).status, 202);
}

TEST(Quotas, RequestRateIs429WithRetryAfter) {
  Principals p;
  p.alice_quotas.requests_per_second = 0.5;
  p.alice_quotas.burst = 3;
  AuthHarness a(p);
  for (int i = 0; i < 3; ++i) EXPECT_EQ(a.as(p.alice, "GET", "/v1/jobs").status, 200) << i;
  const HttpResponse r = a.as(p.alice, "GET", "/v1/jobs");
  expect_problem(r, 429, "fourth request");
  const int retry = std::stoi(std::string(r.header("Retry-After")));
  EXPECT_GE(retry, 1);
  EXPECT_LE(retry, 2);  // one token per 2 s
  EXPECT_NE(r.body.find("requests_per_second"), std::string::npos);
  EXPECT_EQ(a.as(p.bob, "GET", "/v1/jobs").status, 200) << "bob's bucket is his own";
}

// Two principals, one with 8 running jobs and one with 1: over the same interval the
// scheduler's own accounting (compute seconds per owner) must agree within 20%.
// Equal shares are the design; the tolerance covers the chunk granularity (~4 ms
// chunks, whole passes committed) over a 2 s window, ~1000 chunks per owner.
TEST(FairShare, OwnersShareWorkersEquallyWhateverTheirJobCount) {
  ManagerConfig mc = test_manager_config(2);
  auto store = make_memory_store();
  JobManager m(mc, *store, compile_fake_job);
  m.recover();
  Submitter many, one;
  many.owner = "many";
  one.owner = "one";
  std::vector<std::string> ids;
  for (int i = 0; i < 8; ++i) ids.push_back(m.submit(fake_spec(kForever, 20, 100 + i), 0, many)->id());
  ids.push_back(m.submit(fake_spec(kForever, 20, 7), 0, one)->id());
  std::this_thread::sleep_for(std::chrono::milliseconds(500));  // warm up: every job has a block time estimate
  const auto s0 = m.stats().cpu_seconds_by_owner;
  std::this_thread::sleep_for(std::chrono::seconds(2));
  const auto s1 = m.stats().cpu_seconds_by_owner;
  for (const auto& id : ids) m.cancel(id);
  const double a = s1.at("many") - s0.at("many");
  const double b = s1.at("one") - s0.at("one");
  EXPECT_GT(a + b, 1.0) << "the workers computed";
  EXPECT_LE(std::abs(a - b), 0.2 * std::max(a, b)) << "many: " << a << " s, one: " << b << " s";
  m.shutdown();
}

// Polls a stream until it ends or `seconds` pass; returns whether it ended.
bool stream_ends(EventStream& s, double seconds) {
  return wait_until([&] {
    std::string out;
    return !s.poll(out);
  }, seconds);
}

TEST(Revocation, ReloadAddsAtOnceRevokesAtTheNextRequestAndEndsStreams) {
  Principals p;
  AuthHarness a(p);
  const std::string id = a.submit_as(p.alice, fake_spec(kForever, 1));
  HttpResponse ev = a.as(p.alice, "GET", "/v1/jobs/" + id + "/events");
  ASSERT_EQ(ev.status, 200);
  ASSERT_TRUE(ev.stream);
  std::atomic<bool> woken{false};
  std::string out;
  ASSERT_TRUE(ev.stream->poll(out));
  ev.stream->on_ready([&] { woken = true; });
  // Reload: alice is gone, carol is new. Kept principals keep their streams.
  HttpResponse bobs_stream = a.as(p.admin, "GET", "/v1/jobs/" + id + "/events");
  ASSERT_TRUE(bobs_stream.stream);
  AuthFile f = p.file(/*with_alice=*/false);
  const std::string carol = generate_token();
  f.principals.push_back(PrincipalEntry{"carol", Role::user, token_sha256_hex(carol), {}, {}});
  const ReloadResult rr = a.access.reload(f);
  EXPECT_EQ(rr.revoked, 1u);
  EXPECT_EQ(rr.added, 1u);
  EXPECT_TRUE(wait_until([&] { return woken.load(); }, 5)) << "the parked stream is woken by the revocation";
  EXPECT_TRUE(stream_ends(*ev.stream, 1)) << "alice's stream ends";
  std::string more;
  EXPECT_TRUE(bobs_stream.stream->poll(more)) << "the admin's stream goes on";
  expect_problem(a.as(p.alice, "GET", "/v1/jobs"), 401, "revoked alice");
  EXPECT_EQ(a.as(carol, "GET", "/v1/jobs").status, 200) << "carol works at once";
  a.as(p.admin, "DELETE", "/v1/jobs/" + id);
}

std::string cookie_from(const HttpResponse& r) {
  const std::string sc(r.header("Set-Cookie"));
  return sc.substr(0, sc.find(';'));  // "tally_session=..."
}

TEST(Session, LoginGivesAStrictHttpOnlyCookieOriginCheckedAndLogoutEndsStreams) {
  Principals p;
  AuthHarness a(p);
  const HttpRequest::Headers here = {{"host", "127.0.0.1:8080"}};
  HttpResponse bad = a.h.call("POST", "/v1/session", json{{"token", generate_token()}}.dump(), "application/json", here);
  expect_problem(bad, 401, "login with an unknown token");
  HttpResponse in = a.h.call("POST", "/v1/session", json{{"token", p.alice}}.dump(), "application/json", here);
  ASSERT_EQ(in.status, 200) << in.body;
  const std::string set = std::string(in.header("Set-Cookie"));
  EXPECT_NE(set.find("; HttpOnly"), std::string::npos) << set;
  EXPECT_NE(set.find("; SameSite=Strict"), std::string::npos) << set;
  EXPECT_EQ(set.find("Secure"), std::string::npos) << "plain HTTP: no Secure attribute";
  EXPECT_EQ(set.find(p.alice), std::string::npos) << "the cookie is not the token";
  HttpRequest::Headers with_cookie = here;
  with_cookie.emplace_back("cookie", "other=1; " + cookie_from(in));
  const json me = json::parse(a.h.call("GET", "/v1/session", {}, "", with_cookie).body);
  EXPECT_EQ(me.at("name"), "alice");
  EXPECT_EQ(me.at("via_cookie"), true);
  // Writes by cookie need this server's Origin.
  expect_problem(a.h.call("POST", "/v1/jobs", fake_spec(kForever, 1).dump(), "application/json", with_cookie), 403,
                 "cookie write without Origin");
  HttpRequest::Headers foreign = with_cookie;
  foreign.emplace_back("origin", "http://attacker.example");
  expect_problem(a.h.call("POST", "/v1/jobs", fake_spec(kForever, 1).dump(), "application/json", foreign), 403,
                 "cookie write from another origin");
  HttpRequest::Headers same = with_cookie;
  same.emplace_back("origin", "http://127.0.0.1:8080");
  const HttpResponse sub = a.h.call("POST", "/v1/jobs", fake_spec(kForever, 1).dump(), "application/json", same);
  ASSERT_EQ(sub.status, 202) << sub.body;
  const std::string id = json::parse(sub.body).at("id");
  HttpResponse ev = a.h.call("GET", "/v1/jobs/" + id + "/events", {}, "", with_cookie);
  ASSERT_TRUE(ev.stream);
  std::string out;
  ASSERT_TRUE(ev.stream->poll(out));
  const HttpResponse out_r = a.h.call("DELETE", "/v1/session", {}, "", same);
  EXPECT_EQ(out_r.status, 204);
  EXPECT_NE(std::string(out_r.header("Set-Cookie")).find("Max-Age=0"), std::string::npos);
  EXPECT_TRUE(stream_ends(*ev.stream, 1)) << "logout ends the session's streams";
  expect_problem(a.h.call("GET", "/v1/jobs", {}, "", with_cookie), 401, "after logout");
  EXPECT_EQ(a.as(p.alice, "GET", "/v1/jobs").status, 200) << "the token itself still works";
  a.as(p.alice, "DELETE", "/v1/jobs/" + id);
}

// Issue 27 N8: POST /v1/session had no rate limit, and a full session table (10,000) ended
// the session closest to expiry, anyone's: a reader's 10,050 logins in 7.7 s ended the
// admin's browser session. Now one principal's logins are limited (a burst of 10, then
// one per 6 s; beyond, 429 with Retry-After) and the admin's session survives.
TEST(Session, OnePrincipalsLoginFloodIs429AndEndsNoOtherSession) {
  Principals p;
  AuthHarness a(p);
  const HttpRequest::Headers here = {{"host", "127.0.0.1:8080"}};
  auto login = [&](const std::string& token) {
    return a.h.call("POST", "/v1/session", json{{"token", token}}.dump(), "application/json", here);
  };
  const HttpResponse admin_in = login(p.admin);
  ASSERT_EQ(admin_in.status, 200) << admin_in.body;
  HttpRequest::Headers admin_cookie = here;
  admin_cookie.emplace_back("cookie", cookie_from(admin_in));
  const auto t0 = std::chrono::steady_clock::now();
  int ok = 0, limited = 0;
  for (int i = 0; i < 10050; ++i) {
    const HttpResponse r = login(p.rita);
    if (r.status == 200) {
      ++ok;
    } else {
      ASSERT_EQ(r.status, 429) << r.body;
      if (limited++ == 0) {
        expect_problem(r, 429, "the first refused login");
        const int wait = std::stoi(std::string(r.header("Retry-After")));
        EXPECT_GE(wait, 1);
        EXPECT_LE(wait, 6);  // one token every 6 s
        EXPECT_NE(json::parse(r.body).at("detail").get<std::string>().find("too many logins for \"rita\""),
                  std::string::npos)
            << r.body;
      }
    }
  }
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  // The burst, plus what the loop's own duration refilled at one per 6 s.
  EXPECT_GE(ok, 10);
  EXPECT_LE(ok, 10 + static_cast<int>(seconds / 6.0) + 1) << seconds << " s";
  EXPECT_EQ(ok + limited, 10050);
  const HttpResponse me = a.h.call("GET", "/v1/session", {}, "", admin_cookie);
  ASSERT_EQ(me.status, 200) << "the admin's session survives: " << me.body;
  EXPECT_EQ(json::parse(me.body).at("name"), "root");
  // Another principal is not held back by rita's limit.
  EXPECT_EQ(login(p.alice).status, 200);
}

// Sessions opened past the rate limit's reach (slowly, over hours) are bounded per
// principal: at kMaxSessionsPerPrincipal, a principal's new session ends its own oldest.
TEST(Session, APrincipalPastItsShareEndsItsOwnOldestSession) {
  Principals p;
  AccessControl ac(p.file());
  const auto root = ac.authenticate_token(p.admin), rita = ac.authenticate_token(p.rita);
  ASSERT_TRUE(root && rita);
  const std::string admin_sid = ac.open_session(*root);
  std::vector<std::string> rita_sids;
  for (size_t i = 0; i < AccessControl::kMaxSessionsPerPrincipal + 10; ++i) {
    rita_sids.push_back(ac.open_session(*rita, 3600.0 + static_cast<double>(i)));  // later ones expire later
  }
  EXPECT_EQ(ac.session_count(), AccessControl::kMaxSessionsPerPrincipal + 1);
  ASSERT_TRUE(ac.authenticate_session(admin_sid).has_value());
  EXPECT_EQ(ac.authenticate_session(admin_sid)->name, "root");
  for (size_t i = 0; i < rita_sids.size(); ++i) {
    EXPECT_EQ(ac.authenticate_session(rita_sids[i]).has_value(), i >= 10) << "rita's session " << i;
  }
}

TEST(LoginLimiter, PerAddressAndPerPrincipalBucketsExactly) {
  LoginLimiter l(LoginRate{0.5, 2}, LoginRate{1.0, 3});
  for (int i = 0; i < 3; ++i) EXPECT_EQ(l.take_address("10.0.0.1", 100.0), 0.0);
  EXPECT_DOUBLE_EQ(l.take_address("10.0.0.1", 100.0), 1.0);  // one a second
  EXPECT_EQ(l.take_address("10.0.0.2", 100.0), 0.0);         // another address: its own bucket
  EXPECT_EQ(l.take_address("", 100.0), 0.0);                 // no socket: not limited by address
  EXPECT_EQ(l.take_address("10.0.0.1", 101.0), 0.0);
  EXPECT_EQ(l.take_principal("rita", 100.0), 0.0);
  EXPECT_EQ(l.take_principal("rita", 100.0), 0.0);
  EXPECT_DOUBLE_EQ(l.take_principal("rita", 100.0), 2.0);  // one every 2 s
  EXPECT_EQ(l.take_principal("root", 100.0), 0.0);
  EXPECT_EQ(l.take_principal("rita", 102.0), 0.0);
  // The defaults the server uses.
  EXPECT_DOUBLE_EQ(LoginLimiter::kPerPrincipal.burst, 10.0);
  EXPECT_DOUBLE_EQ(1.0 / LoginLimiter::kPerPrincipal.per_second, 6.0);
}

TEST(Metrics, OffLoopbackOnlyAdminOrMetricsRole) {
  Principals p;
  AuthHarness a(p, test_manager_config(), /*metrics_open=*/false);
  expect_problem(a.h.call("GET", "/metrics"), 401, "no token");
  expect_problem(a.as(p.alice, "GET", "/metrics"), 403, "user");
  expect_problem(a.as(p.rita, "GET", "/metrics"), 403, "reader");
  const HttpResponse r = a.as(p.prom, "GET", "/metrics");
  EXPECT_EQ(r.status, 200);
  EXPECT_NE(r.body.find("tally_access_control 1"), std::string::npos);
  EXPECT_NE(r.body.find("tally_insecure_no_auth 0"), std::string::npos);
  EXPECT_EQ(r.body.find(p.prom), std::string::npos);
  EXPECT_EQ(a.as(p.admin, "GET", "/metrics").status, 200);
}

// Without access control (loopback): a Host allowlist against DNS rebinding, an
// Origin check, JSON-only writes, nosniff.
TEST(NoAuthLoopback, HostAllowlistOriginCheckAndJsonOnlyWrites) {
  HandlerConfig hc;
  hc.access.check_host = true;
  hc.access.allowed_hosts.push_back("tally.internal");
  Harness h(test_manager_config(), make_memory_store(), hc);
  const std::string spec = fake_spec(10).dump();
  for (const std::string host : {"attacker.example", "attacker.example:8080", "127.0.0.2:8080", "localhost.attacker.example"}) {
    expect_problem(h.call("POST", "/v1/jobs", spec, "application/json", {{"host", host}}), 403, "POST Host " + host);
    expect_problem(h.call("GET", "/v1/jobs", {}, "", {{"host", host}}), 403, "GET Host " + host);
  }
  for (const std::string host : {"127.0.0.1:8080", "localhost:8080", "LOCALHOST", "[::1]:8080", "tally.internal:80"}) {
    EXPECT_EQ(h.call("POST", "/v1/jobs", spec, "application/json", {{"host", host}}).status, 202) << host;
  }
  // A foreign page in the user's browser: its Origin does not name this server.
  expect_problem(h.call("POST", "/v1/jobs", spec, "application/json",
                        {{"host", "127.0.0.1:8080"}, {"origin", "https://attacker.example"}}),
                 403, "foreign Origin");
  expect_problem(h.call("DELETE", "/v1/jobs/x", {}, "", {{"host", "127.0.0.1:8080"}, {"origin", "http://127.0.0.1:9999"}}),
                 403, "other port");
  EXPECT_EQ(h.call("POST", "/v1/jobs", spec, "application/json",
                   {{"host", "127.0.0.1:8080"}, {"origin", "http://127.0.0.1:8080"}})
                .status,
            202);
  // What an HTML form can send is refused: state-changing routes take JSON only.
  for (const std::string ct : {"text/plain", "application/x-www-form-urlencoded", "multipart/form-data; boundary=x"}) {
    expect_problem(h.call("POST", "/v1/jobs", spec, ct, {{"host", "127.0.0.1:8080"}}), 415, ct);
    expect_problem(h.call("POST", "/v1/jobs/validate", spec, ct, {{"host", "127.0.0.1:8080"}}), 415, ct);
  }
  const HttpResponse ok = h.call("GET", "/v1/jobs", {}, "", {{"host", "127.0.0.1:8080"}});
  EXPECT_EQ(ok.header("X-Content-Type-Options"), "nosniff");
  const json me = json::parse(h.call("GET", "/v1/session").body);
  EXPECT_EQ(me.at("access_control"), false);
}

TEST(Store, OldDatabasesGainAnOwnerColumn) {
  const auto dir = std::filesystem::temp_directory_path() / ("tally_auth_store_" + std::to_string(::getpid()));
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  {
    // The schema before access control.
    SQLite::Database db((dir / "tally.db").string(), SQLite::OPEN_READWRITE | SQLite::OPEN_CREATE);
    db.exec("CREATE TABLE jobs (id TEXT PRIMARY KEY, seq INTEGER NOT NULL, spec TEXT NOT NULL, priority INTEGER NOT NULL,"
            " state TEXT NOT NULL, stop_rule TEXT NOT NULL, error TEXT NOT NULL DEFAULT '',"
            " result TEXT NOT NULL DEFAULT '', checkpoint BLOB, created_at REAL NOT NULL, started_at REAL NOT NULL,"
            " finished_at REAL NOT NULL, updated_at REAL NOT NULL DEFAULT 0)");
    db.exec("INSERT INTO jobs (id, seq, spec, priority, state, stop_rule, created_at, started_at, finished_at)"
            " VALUES ('old', 1, '{}', 0, 'succeeded', '{}', 1, 2, 3)");
  }
  auto store = open_sqlite_store(dir.string());
  auto rows = store->load_all();
  ASSERT_EQ(rows.size(), 1u);
  EXPECT_EQ(rows[0].id, "old");
  EXPECT_EQ(rows[0].owner, "");
  StoredJob j;
  j.id = "new";
  j.seq = 2;
  j.spec = "{}";
  j.state = "queued";
  j.stop_rule = "{}";
  j.owner = "alice";
  store->save(j);
  j.state = "running";
  j.owner = "mallory";  // the owner never changes after the first save
  store->save(j);
  store.reset();
  rows = open_sqlite_store(dir.string())->load_all();
  ASSERT_EQ(rows.size(), 2u);
  EXPECT_EQ(rows[1].owner, "alice");
  EXPECT_EQ(rows[1].state, "running");
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace tally::test
