// Access control over the wire, against the real tally-server: every route x every
// kind of caller with exact statuses and problem+json, on plain HTTP and on TLS (a
// certificate made with openssl at test time); SIGHUP adds and revokes tokens and
// ends a revoked token's event stream; the server refuses to listen off loopback
// without access control; `token new`; the CLI over https with --token/--ca-file.
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <array>
#include <atomic>
#include <cstdio>
#include <fstream>
#include <set>
#include <thread>

#include "server/auth/principal.hpp"
#include "server/auth/token.hpp"
#include "server_process.hpp"

namespace tally::e2e {
namespace {

using nlohmann::json;
namespace fs = std::filesystem;

// Runs a shell command; returns (exit status, stdout+stderr).
std::pair<int, std::string> run(const std::string& cmd, bool with_stderr = true) {
  std::string out;
  FILE* f = ::popen((cmd + (with_stderr ? " 2>&1" : " 2>/dev/null")).c_str(), "r");
  if (!f) return {-1, ""};
  char buf[4096];
  size_t n;
  while ((n = fread(buf, 1, sizeof buf, f)) > 0) out.append(buf, n);
  const int st = ::pclose(f);
  return {WIFEXITED(st) ? WEXITSTATUS(st) : -1, out};
}

bool have_openssl() { return run("openssl version").first == 0; }

// A self-signed certificate for 127.0.0.1 and localhost, valid one day.
void make_certificate(const fs::path& dir) {
  const auto [rc, out] = run("openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes -days 1"
                             " -subj /CN=localhost -addext subjectAltName=DNS:localhost,IP:127.0.0.1"
                             " -keyout " + (dir / "key.pem").string() + " -out " + (dir / "cert.pem").string());
  if (rc != 0) throw std::runtime_error("openssl: " + out);
}

struct Who {
  std::string name, token;
  Role role;
};

void write_auth_file(const fs::path& path, const std::vector<Who>& who) {
  json list = json::array();
  for (const auto& w : who) {
    list.push_back({{"name", w.name}, {"role", std::string(role_name(w.role))}, {"token_sha256", token_sha256_hex(w.token)}});
  }
  const fs::path tmp = path.string() + ".tmp";
  std::ofstream(tmp) << json{{"principals", list}}.dump(2);
  fs::rename(tmp, path);  // atomic, as an operator's editor would (or should)
}

json image_spec(uint64_t max_samples) {
  std::ifstream in(std::string(TALLY_SOURCE_DIR) + "/examples/preview_image.json");
  json spec = json::parse(in);
  spec["stop"] = {{"max_samples", max_samples}};
  return spec;
}

HeaderList json_ct() { return {{"Content-Type", "application/json"}}; }

void expect_problem(const ClientResponse& r, const std::string& what) {
  if (r.status < 400) return;
  EXPECT_EQ(r.header("Content-Type"), "application/problem+json") << what;
  json p;
  ASSERT_NO_THROW(p = json::parse(r.body)) << what << ": " << r.body;
  EXPECT_EQ(p.at("status"), r.status) << what;
  if (r.status == 401) {
    EXPECT_EQ(r.header("WWW-Authenticate").substr(0, 6), "Bearer") << what;
  }
}

// One server with four principals; rita was a user (she submitted a job) and is now
// a reader (SIGHUP), so "reader on its own job" is real.
class AuthServer {
 public:
  explicit AuthServer(bool tls) : tls_(tls) {
    if (tls) make_certificate(dir.path);
    admin = {"root", generate_token(), Role::admin};
    alice = {"alice", generate_token(), Role::user};
    bob = {"bob", generate_token(), Role::user};
    rita = {"rita", generate_token(), Role::user};
    auth_file = dir.path / "auth.json";
    write_auth_file(auth_file, {admin, alice, bob, rita});
    std::vector<std::string> args = {"--auth-file", auth_file.string()};
    if (tls) {
      args.insert(args.end(), {"--tls-cert", (dir.path / "cert.pem").string(), "--tls-key", (dir.path / "key.pem").string()});
    }
    server = std::make_unique<ServerProcess>(dir.path / "data", args);
    auto as_rita = as(rita.token);
    rita_job = submit(as_rita, image_spec(64));
    wait_state(as_rita, rita_job, "succeeded");
    rita.role = Role::reader;
    write_auth_file(auth_file, {admin, alice, bob, rita});
    server->signal(SIGHUP);
    // The reload is done once rita may no longer submit (bounded wait).
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(10);
    while (as_rita.request("POST", "/v1/jobs", disk_spec(10).dump(), json_ct()).status != 403) {
      if (std::chrono::steady_clock::now() > deadline) throw std::runtime_error("SIGHUP reload not seen");
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    auto as_alice = as(alice.token);
    alice_job = submit(as_alice, image_spec(64));
    wait_state(as_alice, alice_job, "succeeded");
  }
  ~AuthServer() {
    if (server) server->terminate();
  }
  HttpClient as(const std::string& token) const {
    ClientSecurity s;
    s.token = token;
    if (tls_) s.ca_file = (dir.path / "cert.pem").string();
    return server->client(s, tls_);
  }
  // A client that sends a raw Authorization header (or none).
  HttpClient anonymous() const { return as(""); }

  TempDir dir;
  bool tls_;
  fs::path auth_file;
  Who admin, alice, bob, rita;
  std::unique_ptr<ServerProcess> server;
  std::string rita_job, alice_job;
};

enum Caller { kNone, kMalformed, kUnknown, kOther, kReader, kUser, kAdmin, kCallers };
const char* const kCallerNames[] = {"no token", "malformed header", "unknown token", "another tenant",
                                    "reader", "user", "admin"};

struct RouteCase {
  std::string method, pattern;  // as in docs/openapi.json
  std::array<int, kCallers> expect;
};

class WireTable : public ::testing::TestWithParam<bool> {};

TEST_P(WireTable, EveryRouteTimesEveryCaller) {
  const bool tls = GetParam();
  if (tls && !have_openssl()) GTEST_SKIP() << "openssl is not installed (scripts/install-deps.sh test)";
  AuthServer s(tls);
  const std::string unknown = generate_token();
  const std::vector<RouteCase> table = {
      {"GET", "/livez", {200, 200, 200, 200, 200, 200, 200}},
      {"GET", "/readyz", {200, 200, 200, 200, 200, 200, 200}},
      {"GET", "/metrics", {200, 200, 200, 200, 200, 200, 200}},  // loopback: open
      {"GET", "/v1/openapi.json", {401, 401, 401, 200, 200, 200, 200}},
      {"GET", "/v1/workers", {401, 401, 401, 403, 403, 403, 200}},  // admin or metrics role
      {"POST", "/v1/jobs", {401, 401, 401, 202, 403, 202, 202}},
      {"GET", "/v1/jobs", {401, 401, 401, 200, 200, 200, 200}},
      {"POST", "/v1/jobs/validate", {401, 401, 401, 200, 403, 200, 200}},
      {"GET", "/v1/jobs/{id}", {401, 401, 401, 404, 200, 200, 200}},
      {"DELETE", "/v1/jobs/{id}", {401, 401, 401, 404, 403, 202, 202}},
      // alice's job has finished: her and the admin's priority change is a 409 (a running
      // job's 200 for both: access_test.cpp, Tenancy).
      {"PATCH", "/v1/jobs/{id}", {401, 401, 401, 404, 403, 409, 409}},
      {"POST", "/v1/jobs/{id}/extend", {401, 401, 401, 404, 403, 409, 409}},
      {"GET", "/v1/jobs/{id}/events", {401, 401, 401, 404, 200, 200, 200}},
      {"GET", "/v1/jobs/{id}/tiles/{n}", {401, 401, 401, 404, 200, 200, 200}},
      {"GET", "/v1/jobs/{id}/image.exr", {401, 401, 401, 404, 200, 200, 200}},
      {"GET", "/v1/jobs/{id}/image.png", {401, 401, 401, 404, 200, 200, 200}},
      {"POST", "/v1/session", {401, 401, 401, 200, 200, 200, 200}},
      {"GET", "/v1/session", {401, 401, 401, 200, 200, 200, 200}},
      {"DELETE", "/v1/session", {401, 401, 401, 204, 204, 204, 204}},
      // The submit role uploads; each principal's first upload of the bytes is 201 for it
      // (assets are private names over shared bytes: docs/api.md "Assets").
      {"PUT", "/v1/assets/{name}", {401, 401, 401, 201, 403, 201, 201}},
  };
  const std::string asset_body = "an asset's bytes";
  // The table covers every operation the API documents.
  auto admin = s.as(s.admin.token);
  const json doc = get_json(admin, "/v1/openapi.json");
  std::set<std::string> documented, tested;
  for (const auto& [path, ops] : doc.at("paths").items()) {
    for (const auto& [method, op] : ops.items()) {
      std::string m = method;
      for (char& c : m) c = static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
      if (m == "GET" || m == "POST" || m == "DELETE" || m == "PUT" || m == "PATCH") documented.insert(m + " " + path);
    }
  }
  for (const auto& rc : table) tested.insert(rc.method + " " + rc.pattern);
  EXPECT_EQ(documented, tested);

  for (int c = 0; c < kCallers; ++c) {
    const Caller caller = static_cast<Caller>(c);
    std::string token;
    HeaderList raw_auth;
    switch (caller) {
      case kNone: break;
      case kMalformed: raw_auth = {{"Authorization", "Token " + s.alice.token}}; break;
      case kUnknown: token = unknown; break;
      case kOther: token = s.bob.token; break;
      case kReader: token = s.rita.token; break;
      case kUser: token = s.alice.token; break;
      case kAdmin: token = s.admin.token; break;
      default: break;
    }
    HttpClient client = s.as(token);
    for (const auto& rc : table) {
      // Whose job the job routes name: the reader's own; everyone else's target is alice's.
      std::string id = caller == kReader ? s.rita_job : s.alice_job;
      if (rc.method == "DELETE" && rc.pattern == "/v1/jobs/{id}" && (caller == kUser || caller == kAdmin)) {
        auto as_alice = s.as(s.alice.token);
        id = submit(as_alice, disk_spec(100'000'000'000ULL));  // a fresh running job of alice's to cancel
      }
      std::string target = rc.pattern;
      if (auto p = target.find("{id}"); p != std::string::npos) target.replace(p, 4, id);
      if (auto p = target.find("{n}"); p != std::string::npos) target.replace(p, 3, "0");
      if (auto p = target.find("{name}"); p != std::string::npos) {
        target.replace(p, 6, "sha256:" + token_sha256_hex(asset_body));  // the SHA-256 of the body
      }
      std::string body;
      if (rc.pattern == "/v1/jobs" || rc.pattern == "/v1/jobs/validate") body = disk_spec(1000).dump();
      if (rc.pattern == "/v1/jobs/{id}/extend") body = R"({"max_samples": 10})";
      if (rc.method == "PATCH") body = R"({"priority": 1})";
      if (rc.pattern == "/v1/assets/{name}") body = asset_body;
      if (rc.pattern == "/v1/session" && rc.method == "POST") {
        body = json{{"token", caller == kMalformed ? std::string("not a token") : token}}.dump();
      }
      HeaderList headers = raw_auth;
      if (!body.empty()) headers.emplace_back("Content-Type", "application/json");
      const std::string what = std::string(kCallerNames[c]) + ": " + rc.method + " " + rc.pattern + (tls ? " (TLS)" : "");
      ClientResponse r;
      if (rc.pattern == "/v1/jobs/{id}/events") {
        r = client.stream(target, headers, [](std::string_view) { return false; }, 10);
      } else {
        r = client.request(rc.method, target, body, headers);
      }
      // A cancel is 202 (stops at the next chunk boundary) or, if no chunk was in flight, 200.
      const bool cancelled_at_once = rc.method == "DELETE" && rc.expect[c] == 202 && r.status == 200;
      if (!cancelled_at_once) {
        EXPECT_EQ(r.status, rc.expect[c]) << what << ": " << r.body;
      }
      expect_problem(r, what);
      if (!token.empty()) {
        EXPECT_EQ(r.body.find(token), std::string::npos) << what << ": the token is echoed";
      }
      if (r.header("Content-Type").find("json") != std::string::npos) {
        EXPECT_EQ(r.header("X-Content-Type-Options"), "nosniff") << what;
      }
    }
  }
  // The list is filtered by tenant.
  auto ids = [&](const std::string& token) {
    auto c = s.as(token);
    std::set<std::string> out;
    const json list = get_json(c, "/v1/jobs");
    for (const auto& j : list.at("jobs")) out.insert(j.at("id"));
    return out;
  };
  EXPECT_FALSE(ids(s.bob.token).count(s.alice_job));
  EXPECT_TRUE(ids(s.alice.token).count(s.alice_job));
  EXPECT_FALSE(ids(s.alice.token).count(s.rita_job));
  EXPECT_TRUE(ids(s.rita.token).count(s.rita_job));
  EXPECT_TRUE(ids(s.admin.token).count(s.rita_job));
  // Tokens never reach the log.
  const std::string log = s.server->log();
  for (const auto& t : {s.admin.token, s.alice.token, s.bob.token, s.rita.token, unknown}) {
    EXPECT_EQ(log.find(t), std::string::npos);
  }
}

INSTANTIATE_TEST_SUITE_P(PlainAndTls, WireTable, ::testing::Values(false, true),
                         [](const ::testing::TestParamInfo<bool>& p) { return p.param ? "Tls" : "Plain"; });

TEST(Sighup, AddsAtOnceRevokesAtTheNextRequestAndClosesTheEventStream) {
  TempDir dir;
  const Who admin{"root", generate_token(), Role::admin}, alice{"alice", generate_token(), Role::user},
      carol{"carol", generate_token(), Role::user};
  const fs::path file = dir.path / "auth.json";
  write_auth_file(file, {admin, alice});
  ServerProcess server(dir.path / "data", {"--auth-file", file.string()});
  auto as_alice = server.client({alice.token, ""});
  auto as_admin = server.client({admin.token, ""});
  auto as_carol = server.client({carol.token, ""});
  EXPECT_EQ(as_carol.request("GET", "/v1/jobs").status, 401);
  const std::string id = submit(as_alice, disk_spec(100'000'000'000ULL));
  wait_state(as_alice, id, "running");

  std::atomic<bool> stream_open{false}, stream_ended{false};
  std::atomic<int> status{0};
  std::thread watcher([&] {
    auto c = server.client({alice.token, ""});
    try {
      const ClientResponse r = c.stream("/v1/jobs/" + id + "/events", {{"Accept", "text/event-stream"}},
                                        [&](std::string_view) {
                                          stream_open = true;
                                          return true;
                                        },
                                        30);
      status = r.status;
    } catch (const std::exception& e) {
      std::fprintf(stderr, "watcher: %s\n", e.what());
      status = -1;
    }
    stream_ended = true;
  });
  struct Joiner {
    std::thread& t;
    ~Joiner() { t.join(); }  // bounded: the stream ends with the revocation or the server
  } joiner{watcher};
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(10);
  while (!stream_open && std::chrono::steady_clock::now() < deadline) std::this_thread::sleep_for(std::chrono::milliseconds(10));
  ASSERT_TRUE(stream_open);

  write_auth_file(file, {admin, carol});
  server.signal(SIGHUP);
  // Wait for the reload's log line; the very next requests see the new principals.
  const auto d2 = std::chrono::steady_clock::now() + std::chrono::seconds(10);
  while (server.log().find("SIGHUP: reloaded") == std::string::npos && std::chrono::steady_clock::now() < d2) {
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  ASSERT_NE(server.log().find("1 added, 1 revoked"), std::string::npos) << server.log();
  EXPECT_EQ(as_carol.request("GET", "/v1/jobs").status, 200) << "a new token works at once";
  const ClientResponse r = as_alice.request("GET", "/v1/jobs");
  EXPECT_EQ(r.status, 401) << "a revoked token is refused on its next request";
  EXPECT_EQ(r.header("WWW-Authenticate"), "Bearer realm=\"tally\", error=\"invalid_token\"");
  const auto d3 = std::chrono::steady_clock::now() + std::chrono::seconds(10);
  while (!stream_ended && std::chrono::steady_clock::now() < d3) std::this_thread::sleep_for(std::chrono::milliseconds(10));
  EXPECT_TRUE(stream_ended) << "the revoked token's event stream is closed";
  EXPECT_EQ(status.load(), 200);
  // Nothing else was dropped: the job runs on, the admin sees it.
  EXPECT_EQ(get_json(as_admin, "/v1/jobs/" + id).at("state"), "running");
  const int cancel = as_admin.request("DELETE", "/v1/jobs/" + id).status;
  EXPECT_TRUE(cancel == 202 || cancel == 200) << cancel;  // 200: cancelled at once, between passes
  // A broken file keeps the previous principals.
  std::ofstream(file) << "{not json";
  server.signal(SIGHUP);
  const auto d4 = std::chrono::steady_clock::now() + std::chrono::seconds(10);
  while (server.log().find("keeping the previous principals") == std::string::npos &&
         std::chrono::steady_clock::now() < d4) {
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  EXPECT_EQ(as_carol.request("GET", "/v1/jobs").status, 200);
  EXPECT_EQ(server.terminate(), 0);
}

TEST(SecureByDefault, RefusesToListenOffLoopbackWithoutAuth) {
  TempDir dir;
  // Refused before binding anything: the test never listens off loopback.
  const auto [rc, out] = run(std::string(TALLY_SERVER_BIN) + " --listen 0.0.0.0:0 --data-dir " + (dir.path / "d").string());
  EXPECT_EQ(rc, 2) << out;
  EXPECT_NE(out.find("refusing to listen on 0.0.0.0 without access control"), std::string::npos) << out;
  const auto [rc6, out6] = run(std::string(TALLY_SERVER_BIN) + " --listen [::]:0 --data-dir " + (dir.path / "d").string());
  EXPECT_EQ(rc6, 2) << out6;
  const auto [rcb, outb] =
      run(std::string(TALLY_SERVER_BIN) + " --listen 127.0.0.1:0 --auth-file " + (dir.path / "missing.json").string());
  EXPECT_EQ(rcb, 2) << "an unreadable auth file stops the start: " << outb;
}

// Over the wire, the default server: loopback, no --auth-file. Its only defence against
// DNS rebinding (a page on attacker.example whose name now resolves to 127.0.0.1) is the
// Host check (server/auth/authorize.cpp check_host): a foreign Host is 403 naming the
// host, on reads and writes, and nothing is done; this machine's names are served. A
// second Host line (which one would the check read?) and a missing one are 400 (RFC 9112
// section 3.2) before any route runs.
TEST(NoAuthWire, ForeignHostIs403AndMissingOrRepeatedHostIs400) {
  TempDir dir;
  ServerProcess server(dir.path / "data");
  HttpClient c = server.client();
  const std::string port = std::to_string(server.port());
  auto exchange = [&](const std::string& method, const std::string& headers, const std::string& body = {}) {
    std::string raw = method + " /v1/jobs HTTP/1.1\r\n" + headers + "Connection: close\r\n";
    if (!body.empty()) raw += "Content-Type: application/json\r\nContent-Length: " + std::to_string(body.size()) + "\r\n";
    return c.raw_exchange(raw + "\r\n" + body);
  };
  auto detail_of = [](const std::string& answer) {
    const json p = json::parse(answer.substr(answer.find("\r\n\r\n") + 4), nullptr, false);
    return p.is_object() ? p.value("detail", "") : std::string();
  };
  const std::string spec = json{{"kind", "integrate"}, {"integrand", "x"}, {"domain", {{0, 1}}},
                                {"stop", {{"max_samples", 1000}}}}.dump();
  for (const std::string& host : {std::string("attacker.example"), "attacker.example:" + port, "127.0.0.2:" + port}) {
    const std::string get = exchange("GET", "Host: " + host + "\r\n");
    EXPECT_EQ(get.substr(0, 13), "HTTP/1.1 403 ") << get;
    EXPECT_EQ(detail_of(get), "Host \"" + host.substr(0, host.find(':')) +
                                  "\" is not allowed (server without access control; add it with --allowed-host)")
        << get;
    const std::string post = exchange("POST", "Host: " + host + "\r\n", spec);
    EXPECT_EQ(post.substr(0, 13), "HTTP/1.1 403 ") << post;
  }
  EXPECT_EQ(get_json(c, "/v1/jobs").at("jobs").size(), 0u) << "a refused POST made no job";
  EXPECT_EQ(exchange("GET", "Host: 127.0.0.1:" + port + "\r\n").substr(0, 13), "HTTP/1.1 200 ");
  EXPECT_EQ(exchange("GET", "Host: localhost:" + port + "\r\n").substr(0, 13), "HTTP/1.1 200 ");
  const std::string dup = exchange("GET", "Host: 127.0.0.1:" + port + "\r\nHost: attacker.example\r\n");
  EXPECT_EQ(dup.substr(0, 13), "HTTP/1.1 400 ") << dup;
  EXPECT_EQ(detail_of(dup), "the request has more than one Host header (RFC 9112 section 3.2)") << dup;
  const std::string none = exchange("GET", "");
  EXPECT_EQ(none.substr(0, 13), "HTTP/1.1 400 ") << none;
  EXPECT_EQ(detail_of(none), "an HTTP/1.1 request needs a Host header (RFC 9112 section 3.2)") << none;
  EXPECT_EQ(server.terminate(), 0);
}

TEST(TokenNew, PrintsTheTokenOnceAndTheEntryWithItsHash) {
  const auto [rc, out] = run(std::string(TALLY_SERVER_BIN) + " token new alice --role reader", /*with_stderr=*/false);
  ASSERT_EQ(rc, 0) << out;
  const size_t nl = out.find('\n');
  const std::string token = out.substr(0, nl);
  const json entry = json::parse(out.substr(nl + 1));
  EXPECT_EQ(token.size(), 47u);
  EXPECT_EQ(entry.at("name"), "alice");
  EXPECT_EQ(entry.at("role"), "reader");
  EXPECT_EQ(entry.at("token_sha256"), token_sha256_hex(token));
  EXPECT_EQ(entry.dump().find(token), std::string::npos) << "the entry holds only the hash";
  EXPECT_EQ(run(std::string(TALLY_SERVER_BIN) + " token new alice --role root").first, 2);
}

TEST(Cli, HttpsWithTokenAndCaFileAndVerifiesByDefault) {
  if (std::string(TALLY_CLI_BIN).empty()) GTEST_SKIP() << "the tally CLI is not built";
  if (!have_openssl()) GTEST_SKIP() << "openssl is not installed";
  TempDir dir;
  make_certificate(dir.path);
  const Who alice{"alice", generate_token(), Role::user};
  write_auth_file(dir.path / "auth.json", {alice});
  ServerProcess server(dir.path / "data", {"--auth-file", (dir.path / "auth.json").string(), "--tls-cert",
                                           (dir.path / "cert.pem").string(), "--tls-key", (dir.path / "key.pem").string()});
  const std::string url = "https://127.0.0.1:" + std::to_string(server.port());
  const std::string cli = std::string(TALLY_CLI_BIN);
  const std::string ca = " --ca-file " + (dir.path / "cert.pem").string();
  // Token from the environment.
  auto [rc, out] = run("TALLY_TOKEN=" + alice.token + " " + cli + " list --server " + url + ca);
  EXPECT_EQ(rc, 0) << out;
  // And from --token.
  std::tie(rc, out) = run(cli + " list --server " + url + ca + " --token " + alice.token);
  EXPECT_EQ(rc, 0) << out;
  // No token: the server's 401 detail.
  std::tie(rc, out) = run(cli + " list --server " + url + ca);
  EXPECT_NE(rc, 0);
  EXPECT_NE(out.find("401"), std::string::npos) << out;
  // The self-signed certificate is not trusted without --ca-file.
  std::tie(rc, out) = run(cli + " list --server " + url + " --token " + alice.token);
  EXPECT_NE(rc, 0) << out;
  EXPECT_NE(out.find("certificate"), std::string::npos) << out;
  // Plain HTTP to the TLS port gets nowhere.
  auto plain = server.client({alice.token, ""});
  EXPECT_THROW(plain.request("GET", "/v1/jobs"), ConnectionError);
  EXPECT_EQ(server.terminate(), 0);
}

}  // namespace
}  // namespace tally::e2e
