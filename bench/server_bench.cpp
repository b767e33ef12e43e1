// Server benchmark (prints figures; not a timed test). Needs wrk and a built
// tally-server (argv[1], or $TALLY_SERVER_BIN, or ./server/tally-server).
//  1. requests/s of GET /v1/jobs/{id} on tally-server vs a minimal Beast server
//     answering a fixed body, same wrk settings, same run, one I/O thread each;
//  2. a running job's samples/s with 0 vs 100 concurrent event-stream watchers.
#include <utility>  // before Asio (Boost 1.74 + GCC 12)

#include <arpa/inet.h>
#include <netinet/in.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <boost/asio.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <regex>
#include <string>
#include <thread>
#include <vector>

#include "tests/support/loopback_socket.hpp"

namespace beast = boost::beast;
namespace http = beast::http;
namespace net = boost::asio;
using tcp = net::ip::tcp;
using nlohmann::json;

namespace {

// ---- the minimal Beast server: keep-alive, fixed JSON body.
class MinimalSession : public std::enable_shared_from_this<MinimalSession> {
 public:
  explicit MinimalSession(tcp::socket s) : stream_(std::move(s)) {}
  void run() { read(); }

 private:
  void read() {
    req_ = {};
    http::async_read(stream_, buf_, req_, [self = shared_from_this()](beast::error_code ec, size_t) {
      if (ec) return;
      auto res = std::make_shared<http::response<http::string_body>>(http::status::ok, self->req_.version());
      res->set(http::field::content_type, "application/json");
      res->body() = R"({"id":"0123456789abcdef","state":"succeeded"})";
      res->keep_alive(self->req_.keep_alive());
      res->prepare_payload();
      http::async_write(self->stream_, *res, [self, res](beast::error_code ec2, size_t) {
        if (!ec2 && res->keep_alive()) self->read();
      });
    });
  }
  beast::tcp_stream stream_;
  beast::flat_buffer buf_;
  http::request<http::string_body> req_;
};

void accept_loop(tcp::acceptor& a) {
  a.async_accept([&a](beast::error_code ec, tcp::socket s) {
    if (!ec) std::make_shared<MinimalSession>(std::move(s))->run();
    accept_loop(a);
  });
}

// ---- tiny blocking HTTP helpers over POSIX sockets (tests/support/loopback_socket.hpp).
using tally::test::connect_loopback;
using tally::test::send_all;

std::string exchange(uint16_t port, const std::string& method, const std::string& target, const std::string& body = {}) {
  const int fd = connect_loopback(port);
  if (fd < 0) return {};
  std::string req = method + " " + target + " HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n";
  if (!body.empty()) req += "Content-Type: application/json\r\nContent-Length: " + std::to_string(body.size()) + "\r\n";
  req += "\r\n" + body;
  (void)send_all(fd, req);
  std::string out;
  char b[65536];
  for (ssize_t n; (n = ::read(fd, b, sizeof b)) > 0;) out.append(b, static_cast<size_t>(n));
  ::close(fd);
  const size_t p = out.find("\r\n\r\n");
  return p == std::string::npos ? std::string{} : out.substr(p + 4);
}

double wrk_rps(const std::string& url, const std::string& duration) {
  const std::string cmd = "wrk -t1 -c32 -d" + duration + " " + url + " 2>&1";
  FILE* p = ::popen(cmd.c_str(), "r");
  std::string out;
  char b[4096];
  for (size_t n; (n = std::fread(b, 1, sizeof b, p)) > 0;) out.append(b, n);
  ::pclose(p);
  std::smatch m;
  if (std::regex_search(out, m, std::regex(R"(Requests/sec:\s+([0-9.]+))"))) return std::stod(m[1]);
  std::fprintf(stderr, "wrk output not understood:\n%s\n", out.c_str());
  return 0;
}

// Samples computed by the workers so far: the chunk-granular counter of /metrics
// (a job's own count only moves at pass boundaries, too coarse for short windows).
double samples_total(uint16_t port) {
  const std::string b = exchange(port, "GET", "/metrics");
  std::smatch m;
  if (std::regex_search(b, m, std::regex(R"(\ntally_samples_total ([0-9.e+]+))"))) return std::stod(m[1]);
  return -1;
}

// samples/s of the workers over `seconds` of wall time.
double rate_over(uint16_t port, const std::string&, double seconds) {
  const double s0 = samples_total(port);
  const auto t0 = std::chrono::steady_clock::now();
  std::this_thread::sleep_for(std::chrono::duration<double>(seconds));
  const double s1 = samples_total(port);
  return (s1 - s0) / std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

}  // namespace

int main(int argc, char** argv) {
  std::string server_bin = argc > 1 ? argv[1] : (std::getenv("TALLY_SERVER_BIN") ? std::getenv("TALLY_SERVER_BIN") : "./server/tally-server");
  const std::string duration = argc > 2 ? argv[2] : "5s";
  if (!std::filesystem::exists(server_bin)) {
    std::fprintf(stderr, "usage: server_bench [path/to/tally-server] [wrk duration]\n");
    return 2;
  }
  ::signal(SIGPIPE, SIG_IGN);

  // Minimal server, one I/O thread.
  net::io_context ioc;
  tcp::acceptor acc(ioc, tcp::endpoint(net::ip::make_address("127.0.0.1"), 0));
  const uint16_t min_port = acc.local_endpoint().port();
  accept_loop(acc);
  std::thread io([&] { ioc.run(); });

  // tally-server, one I/O thread, two workers.
  const auto dir = std::filesystem::temp_directory_path() / ("tally_bench_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  const std::string port_file = (dir / "port").string();
  const pid_t pid = ::fork();
  if (pid == 0) {
    std::freopen((dir / "log").c_str(), "w", stdout);
    ::execl(server_bin.c_str(), server_bin.c_str(), "--listen", "127.0.0.1:0", "--port-file", port_file.c_str(),
            "--data-dir", (dir / "data").c_str(), "--io-threads", "1", "--workers", "2", "--max-connections", "4096",
            static_cast<char*>(nullptr));
    ::_exit(127);
  }
  uint16_t port = 0;
  for (int i = 0; i < 3000 && port == 0; ++i) {
    std::ifstream in(port_file);
    unsigned p = 0;
    if (in >> p) port = static_cast<uint16_t>(p);
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  if (port == 0) {
    std::fprintf(stderr, "tally-server did not start\n");
    return 1;
  }
  auto disk = [](uint64_t n) {
    return json{{"kind", "integrate"}, {"integrand", {{"builtin", "unit_disk"}}},
                {"domain", {{"type", "box"}, {"lower", {-1, -1}}, {"upper", {1, 1}}}},
                {"estimator", {{"type", "uniform"}}}, {"seed", 1}, {"stop", {{"max_samples", n}}}}
        .dump();
  };
  const std::string id = json::parse(exchange(port, "POST", "/v1/jobs", disk(1'000'000))).at("id");
  std::this_thread::sleep_for(std::chrono::milliseconds(500));  // finished: a full status document

  // The machine may be shared: alternate the two servers and take medians.
  auto median = [](std::vector<double> v) {
    std::sort(v.begin(), v.end());
    return v.empty() ? 0.0 : v[v.size() / 2];
  };
  std::printf("== GET /v1/jobs/{id} vs a minimal Beast server (wrk -t1 -c32 -d%s x3 alternating, 1 I/O thread each)\n",
              duration.c_str());
  const std::string body = exchange(port, "GET", "/v1/jobs/" + id);
  std::printf("status document: %zu bytes\n", body.size());
  std::vector<double> mins, tallies, ratios;
  for (int round = 0; round < 3; ++round) {
    const double m = wrk_rps("http://127.0.0.1:" + std::to_string(min_port) + "/", duration);
    const double t = wrk_rps("http://127.0.0.1:" + std::to_string(port) + "/v1/jobs/" + id, duration);
    mins.push_back(m);
    tallies.push_back(t);
    ratios.push_back(m > 0 ? t / m : 0.0);
    std::printf("  round %d: minimal %8.0f req/s, tally %8.0f req/s, ratio %.2f\n", round + 1, m, t, ratios.back());
  }
  std::printf("minimal Beast server: %10.0f req/s (median)\n", median(mins));
  std::printf("tally-server        : %10.0f req/s (median)\n", median(tallies));
  std::printf("ratio               : %10.2f   (median of rounds; goal >= 0.5)\n", median(ratios));

  std::printf("\n== samples/s of a running job, 0 vs 100 event-stream watchers (2 workers, 4 alternating rounds)\n");
  const std::string long_id = json::parse(exchange(port, "POST", "/v1/jobs", disk(90'000'000'000ULL))).at("id");
  std::this_thread::sleep_for(std::chrono::seconds(2));  // past the small first passes
  const double window = 3.0;
  std::vector<double> losses, bases, watcheds;
  size_t total_bytes = 0, connected = 0;
  for (int round = 0; round < 4; ++round) {
    const double base = rate_over(port, long_id, window);
    std::vector<int> fds;
    std::vector<std::thread> readers;
    std::atomic<size_t> bytes{0};
    for (int i = 0; i < 100; ++i) {
      const int fd = connect_loopback(port);
      if (fd < 0) continue;
      const std::string req =
          "GET /v1/jobs/" + long_id + "/events HTTP/1.1\r\nHost: x\r\nAccept: text/event-stream\r\n\r\n";
      (void)send_all(fd, req);
      fds.push_back(fd);
    }
    for (int fd : fds) {
      readers.emplace_back([fd, &bytes] {
        char b[16384];
        for (ssize_t n; (n = ::read(fd, b, sizeof b)) > 0;) bytes += static_cast<size_t>(n);
      });
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(300));
    const double watched = rate_over(port, long_id, window);
    for (int fd : fds) ::shutdown(fd, SHUT_RDWR);
    for (auto& t : readers) t.join();
    for (int fd : fds) ::close(fd);
    connected = fds.size();
    total_bytes += bytes.load();
    bases.push_back(base);
    watcheds.push_back(watched);
    losses.push_back(base > 0 ? 100.0 * (1.0 - watched / base) : 0.0);
    std::printf("  round %d: no watchers %.3g samples/s, %zu watchers %.3g samples/s, loss %.1f %%\n", round + 1, base,
                fds.size(), watched, losses.back());
    std::this_thread::sleep_for(std::chrono::milliseconds(300));
  }
  std::printf("watchers connected  : %zu per round (%zu bytes of events received in all)\n", connected, total_bytes);
  std::printf("no watchers         : %10.3g samples/s (median)\n", median(bases));
  std::printf("100 watchers        : %10.3g samples/s (median)\n", median(watcheds));
  std::printf("loss                : %10.1f %%  (median of rounds; goal <= 5%%)\n", median(losses));

  exchange(port, "DELETE", "/v1/jobs/" + long_id);
  ::kill(pid, SIGTERM);
  int st = 0;
  ::waitpid(pid, &st, 0);
  ioc.stop();
  io.join();
  std::filesystem::remove_all(dir);
  return 0;
}
