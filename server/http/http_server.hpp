#pragma once
// The network side: listener and sessions on Boost.Beast (this header keeps
// Beast out of everyone else's translation units). Every connection has a body
// limit, a header limit, an idle timeout (waiting for a request), a read timeout
// (the whole request once its first byte arrived: a client dribbling one byte per
// second is cut off) and a write timeout.
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <string_view>

namespace tally {

class HttpHandler;
struct ConnectionCounters;

struct HttpServerConfig {
  std::string address = "127.0.0.1";
  uint16_t port = 8080;  // 0: any free port (see HttpServer::port())
  unsigned io_threads = 1;
  size_t max_body_bytes = 1 << 20;
  size_t max_header_bytes = 16 << 10;
  double idle_timeout_s = 60;
  double read_timeout_s = 10;
  double write_timeout_s = 30;
  double heartbeat_s = 15;  // comment line on idle event streams
  size_t max_connections = 1024;
  // The slow lane (validate pilots): its own threads, and at most this many
  // requests running or waiting there; beyond that 503 + Retry-After.
  unsigned slow_threads = 2;
  size_t max_slow_requests = 8;
  // Both set: HTTPS (PEM certificate chain and private key); both empty: plain HTTP.
  std::string tls_cert, tls_key;
};

class HttpServer {
 public:
  HttpServer(HttpServerConfig config, HttpHandler& handler, ConnectionCounters& counters);
  ~HttpServer();
  HttpServer(const HttpServer&) = delete;
  HttpServer& operator=(const HttpServer&) = delete;

  // Binds and listens (throws on failure); returns the bound port.
  uint16_t start();
  uint16_t port() const;
  // Runs `fn` when SIGINT or SIGTERM arrives (on an I/O thread).
  void on_signal(std::function<void(int)> fn);
  // Runs `fn` on every SIGHUP (on an I/O thread), e.g. to reload the auth file.
  void on_hangup(std::function<void()> fn);
  void stop_accepting();
  // Waits up to `seconds` for open connections to finish, then stops the I/O threads.
  void stop(double grace_seconds);
  size_t open_connections() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// The session's parsing, limits and framing rules without a socket (for tests and
// fuzzers): answers every request in `raw` in order through `handler`, as the
// server would on one connection, and returns the response bytes. Input that ends
// mid-request gets the 408 a read timeout would give; event streams are answered
// with their header only.
std::string respond_to_bytes(std::string_view raw, const HttpServerConfig& config, HttpHandler& handler);

}  // namespace tally
