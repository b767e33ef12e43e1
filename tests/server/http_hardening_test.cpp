// The HTTP plumbing against hostile input: request smuggling framing, read
// timeouts answered with 408, descriptor exhaustion, metric label cardinality.
// Parsing tests go through respond_to_bytes (the session's rules without a socket);
// the descriptor test runs the real listener in this process.
#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <unistd.h>

#include <fmt/format.h>

#include <filesystem>

#include "client/http_client.hpp"
#include "server/http/fd_limit.hpp"
#include "server/http/http_framing.hpp"
#include "server/http/http_server.hpp"
#include "server_test_support.hpp"

namespace tally::test {
namespace {

size_t count(const std::string& hay, const std::string& needle) {
  size_t n = 0;
  for (size_t p = hay.find(needle); p != std::string::npos; p = hay.find(needle, p + 1)) ++n;
  return n;
}

TEST(HttpFraming, TransferEncodingMustEndWithChunked) {
  EXPECT_FALSE(transfer_encoding_problem(""));
  EXPECT_FALSE(transfer_encoding_problem("chunked"));
  EXPECT_FALSE(transfer_encoding_problem(" Chunked "));
  EXPECT_EQ(transfer_encoding_problem("chunked, identity")->status, 400);
  EXPECT_EQ(transfer_encoding_problem("gzip")->status, 400);
  EXPECT_EQ(transfer_encoding_problem("identity")->status, 400);
  EXPECT_EQ(transfer_encoding_problem(",")->status, 400);
  EXPECT_EQ(transfer_encoding_problem("chunked, chunked")->status, 400);
  EXPECT_EQ(transfer_encoding_problem("gzip, chunked")->status, 501);
}

// Before the fix, the body after "Transfer-Encoding: chunked, identity" was read as a
// second request on the same connection (two answers to one request: smuggling).
TEST(HttpFraming, SmuggledSecondRequestIsNotAnswered) {
  Harness h;
  HttpServerConfig cfg;
  for (const std::string te : {"chunked, identity", "gzip", "identity"}) {
    const std::string raw = "POST /v1/jobs/validate HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
                            "Transfer-Encoding: " + te + "\r\n\r\nGET /livez HTTP/1.1\r\nHost: x\r\n\r\n";
    const std::string out = respond_to_bytes(raw, cfg, *h.handler);
    EXPECT_EQ(count(out, "HTTP/1.1 "), 1u) << te << "\n" << out;
    EXPECT_EQ(out.rfind("HTTP/1.1 400 Bad Request\r\n", 0), 0u) << out;
    EXPECT_NE(out.find("Connection: close"), std::string::npos) << out;
    EXPECT_NE(out.find("application/problem+json"), std::string::npos) << out;
  }
  // Two pipelined well-framed requests get two answers.
  const std::string two = respond_to_bytes(
      "GET /livez HTTP/1.1\r\nHost: x\r\n\r\nGET /livez HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n", cfg,
      *h.handler);
  EXPECT_EQ(count(two, "HTTP/1.1 200 OK"), 2u) << two;
}

// Issue 27 N14: with two Host lines the first one won (a proxy or a check reading the
// other one sees another authority), and an HTTP/1.1 request without Host got 200.
// RFC 9112 section 3.2: 400 for both, before any route runs; HTTP/1.0 may omit Host.
TEST(HttpFraming, HostMissingOrRepeatedIs400) {
  Harness h;
  HttpServerConfig cfg;
  const std::string dup =
      respond_to_bytes("GET /livez HTTP/1.1\r\nHost: 127.0.0.1\r\nHost: attacker.example\r\n\r\n", cfg, *h.handler);
  EXPECT_EQ(dup.rfind("HTTP/1.1 400 Bad Request\r\n", 0), 0u) << dup;
  EXPECT_NE(dup.find("more than one Host header"), std::string::npos) << dup;
  EXPECT_NE(dup.find("Connection: close"), std::string::npos) << dup;
  const std::string none = respond_to_bytes("GET /livez HTTP/1.1\r\n\r\n", cfg, *h.handler);
  EXPECT_EQ(none.rfind("HTTP/1.1 400 Bad Request\r\n", 0), 0u) << none;
  EXPECT_NE(none.find("an HTTP/1.1 request needs a Host header"), std::string::npos) << none;
  // The rules hold for a streamed-body route's header too (checked before the route).
  const std::string put = respond_to_bytes("PUT /v1/assets/sha256:" + std::string(64, 'a') +
                                               " HTTP/1.1\r\nContent-Length: 1\r\n\r\nx",
                                           cfg, *h.handler);
  EXPECT_EQ(put.rfind("HTTP/1.1 400 Bad Request\r\n", 0), 0u) << put;
  const std::string one = respond_to_bytes("GET /livez HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n", cfg, *h.handler);
  EXPECT_EQ(one.rfind("HTTP/1.1 200 OK\r\n", 0), 0u) << one;
  const std::string http10 = respond_to_bytes("GET /livez HTTP/1.0\r\n\r\n", cfg, *h.handler);
  EXPECT_EQ(http10.rfind("HTTP/1.0 200 OK\r\n", 0), 0u) << http10;
  EXPECT_FALSE(host_problem(1, 11).has_value());
  EXPECT_FALSE(host_problem(0, 10).has_value());
  EXPECT_EQ(host_problem(2, 10)->status, 400);
}

TEST(HttpFraming, RequestCutOffGets408) {
  Harness h;
  HttpServerConfig cfg;
  const std::string out = respond_to_bytes("POST /v1/jobs HTTP/1.1\r\nHost: x\r\nContent-Length: 50\r\n\r\n{\"a", cfg,
                                           *h.handler);
  EXPECT_EQ(out.rfind("HTTP/1.1 408 Request Timeout\r\n", 0), 0u) << out;
}

// 1,000 requests with unique 8 KB methods made /metrics 129 MB: labels must come
// from closed sets.
TEST(HttpMetrics, UnknownMethodsDoNotGrowTheLabelSet) {
  Harness h;
  HttpServerConfig cfg;
  cfg.max_header_bytes = 16 << 10;
  for (int i = 0; i < 1000; ++i) {
    std::string method = fmt::format("M{:04}", i) + std::string(8192 - 5, 'X');
    const std::string out = respond_to_bytes(method + " /v1/jobs HTTP/1.1\r\nHost: x\r\n\r\n", cfg, *h.handler);
    ASSERT_NE(out.find(" 405 "), std::string::npos) << out.substr(0, 200);
  }
  const auto m = h.call("GET", "/metrics");
  EXPECT_LT(m.body.size(), 32u << 10) << "metrics grew to " << m.body.size() << " bytes";
  EXPECT_NE(m.body.find("tally_http_requests_total{route=\"unmatched\",method=\"other\",status=\"405\"} 1000"),
            std::string::npos)
      << m.body;
  EXPECT_EQ(Metrics::method_label("GET"), "GET");
  EXPECT_EQ(Metrics::method_label("get"), "other");
  EXPECT_EQ(Metrics::method_label("PROPFIND"), "other");
}

TEST(FdLimit, ConnectionsStayBelowTheDescriptorLimit) {
  EXPECT_EQ(connections_for_fd_limit(1024, 1024), 960u);
  EXPECT_EQ(connections_for_fd_limit(100, 1024), 100u);
  EXPECT_EQ(connections_for_fd_limit(1024, 10), 1u);
  EXPECT_EQ(connections_for_fd_limit(1024, 65536), 1024u);
  rlimit rl{};
  ASSERT_EQ(getrlimit(RLIMIT_NOFILE, &rl), 0);
  const size_t soft = raise_fd_soft_limit();
  if (rl.rlim_max != RLIM_INFINITY) {
    EXPECT_EQ(soft, rl.rlim_max);
  }
}

size_t open_descriptors() {
  size_t n = 0;
  for ([[maybe_unused]] const auto& e : std::filesystem::directory_iterator("/proc/self/fd")) ++n;
  return n;
}

// When descriptors run out, accept fails with EMFILE while the connection stays in
// the backlog; re-arming at once spun (11,070 failed accepts in 2 s). With the
// back-off there are at most ~10 a second, and the server serves again afterwards.
TEST(HttpServerFds, AcceptBacksOffWhenDescriptorsRunOut) {
  Harness h;
  HttpServerConfig cfg;
  cfg.port = 0;
  cfg.max_connections = 100000;  // the descriptor limit, not this, is reached
  HttpServer server(cfg, *h.handler, h.metrics);
  const uint16_t port = server.start();

  rlimit saved{};
  ASSERT_EQ(getrlimit(RLIMIT_NOFILE, &saved), 0);
  rlimit low = saved;
  low.rlim_cur = open_descriptors() + 24;
  ASSERT_EQ(setrlimit(RLIMIT_NOFILE, &low), 0);

  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(port);
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  std::vector<int> clients;
  for (int i = 0; i < 200; ++i) {
    const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
    if (fd < 0) break;  // this process (clients and server together) is out of descriptors
    clients.push_back(fd);
    if (::connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0) break;
  }
  ASSERT_LT(clients.size(), 200u) << "the descriptor limit was not reached";
  const uint64_t before = h.metrics.accept_errors.load();
  std::this_thread::sleep_for(std::chrono::seconds(1));
  const uint64_t failed = h.metrics.accept_errors.load() - before;
  EXPECT_LE(failed, 15u) << "accept retried without backing off";
  EXPECT_GE(h.metrics.accept_errors.load(), 1u) << "the test did not exhaust descriptors";

  for (int fd : clients) ::close(fd);
  ASSERT_EQ(setrlimit(RLIMIT_NOFILE, &saved), 0);
  HttpUrl url;
  url.port = std::to_string(port);
  HttpClient c(url, 10);
  EXPECT_TRUE(wait_until(
      [&] {
        try {
          return c.request("GET", "/livez").status == 200;
        } catch (const std::exception& e) {
          return false;  // still draining the backlog
        }
      },
      10));
  server.stop(1.0);
}

}  // namespace
}  // namespace tally::test
