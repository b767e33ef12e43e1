// `tally preview ID --tev HOST:PORT` against a real tally-server and a fake tev (a
// TCP listener in this test): the bytes the bridge sends are decoded packet by
// packet, replayed into an image, and compared with the server's EXR of the same
// (finished) job state, channel by channel, selected by name. A second test stops
// the fake tev mid-job and starts it again on the same port: the bridge must
// reconnect and re-send the whole image.
#include <cctype>
#include <arpa/inet.h>
#include <fcntl.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <poll.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <fmt/format.h>
#include <OpenImageIO/imageio.h>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <nlohmann/json.hpp>
#include <sstream>
#include <thread>

#include "client/http_client.hpp"
#include "client/tev_bridge.hpp"
#include "preview/tev_decoder.hpp"

namespace tally {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using namespace std::chrono_literals;

fs::path temp_dir(const std::string& tag) {
  fs::path d = fs::temp_directory_path() / fmt::format("tally-{}-{}-{}", tag, ::getpid(),
                                                       std::chrono::steady_clock::now().time_since_epoch().count());
  fs::create_directories(d);
  return d;
}

// A child process with stdout+stderr in a log file.
class Child {
 public:
  Child(const std::vector<std::string>& argv, const fs::path& log) : log_(log) {
    pid_ = ::fork();
    if (pid_ == 0) {
      const int fd = ::open(log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
      ::dup2(fd, 1);
      ::dup2(fd, 2);
      std::vector<char*> a;
      for (const auto& s : argv) a.push_back(const_cast<char*>(s.c_str()));
      a.push_back(nullptr);
      ::execv(a[0], a.data());
      ::_exit(127);
    }
  }
  ~Child() {
    if (pid_ > 0 && !exited_) {
      ::kill(pid_, SIGKILL);
      ::waitpid(pid_, nullptr, 0);
    }
  }
  // Exit status, or nullopt if still running after `timeout`.
  std::optional<int> wait(std::chrono::milliseconds timeout) {
    const auto end = std::chrono::steady_clock::now() + timeout;
    while (std::chrono::steady_clock::now() < end) {
      int st = 0;
      if (::waitpid(pid_, &st, WNOHANG) == pid_) {
        exited_ = true;
        return WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
      }
      std::this_thread::sleep_for(20ms);
    }
    return std::nullopt;
  }
  void terminate() {
    if (!exited_) {
      ::kill(pid_, SIGTERM);
      if (!wait(10s)) {
        ::kill(pid_, SIGKILL);
        wait(5s);
      }
    }
  }
  std::string log() const {
    std::ifstream in(log_);
    std::stringstream ss;
    ss << in.rdbuf();
    return ss.str();
  }

 private:
  pid_t pid_ = -1;
  bool exited_ = false;
  fs::path log_;
};

// The fake tev: accepts connections one after another and keeps every byte of each.
class FakeTev {
 public:
  explicit FakeTev(uint16_t port = 0) { listen_on(port); }
  ~FakeTev() { stop(); }

  uint16_t port() const { return port_; }
  void listen_on(uint16_t port) {
    lfd_ = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    const int one = 1;
    ::setsockopt(lfd_, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_port = htons(port);
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    if (::bind(lfd_, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0) throw std::runtime_error("bind failed");
    ::listen(lfd_, 4);
    socklen_t len = sizeof a;
    ::getsockname(lfd_, reinterpret_cast<sockaddr*>(&a), &len);
    port_ = ntohs(a.sin_port);
    running_ = true;
    thread_ = std::thread([this] { serve(); });
  }
  // tev quits: the listener and the open connection close at once.
  void stop() {
    running_ = false;
    if (thread_.joinable()) thread_.join();
    if (lfd_ >= 0) ::close(lfd_);
    lfd_ = -1;
  }
  std::vector<std::string> connections() const {
    std::lock_guard lock(mu_);
    return conns_;
  }
  size_t bytes() const {
    std::lock_guard lock(mu_);
    size_t n = 0;
    for (const auto& c : conns_) n += c.size();
    return n;
  }
  size_t eofs() const { return eofs_; }

 private:
  void serve() {
    while (running_) {
      pollfd p{lfd_, POLLIN, 0};
      if (::poll(&p, 1, 50) <= 0) continue;
      const int fd = ::accept4(lfd_, nullptr, nullptr, SOCK_CLOEXEC);
      if (fd < 0) continue;
      size_t idx;
      {
        std::lock_guard lock(mu_);
        conns_.emplace_back();
        idx = conns_.size() - 1;
      }
      char buf[65536];
      while (running_) {
        pollfd q{fd, POLLIN, 0};
        if (::poll(&q, 1, 50) <= 0) continue;
        const ssize_t n = ::recv(fd, buf, sizeof buf, 0);
        if (n <= 0) {
          if (n == 0) ++eofs_;
          break;
        }
        std::lock_guard lock(mu_);
        conns_[idx].append(buf, static_cast<size_t>(n));
      }
      ::close(fd);  // tev's side of a clean disconnect (or tev quitting)
    }
  }
  int lfd_ = -1;
  uint16_t port_ = 0;
  std::atomic<bool> running_{false};
  std::atomic<size_t> eofs_{0};
  std::thread thread_;
  mutable std::mutex mu_;
  std::vector<std::string> conns_;
};

struct Server {
  fs::path dir;
  std::unique_ptr<Child> proc;
  uint16_t port = 0;

  Server() {
    dir = temp_dir("tev-server");
    proc = std::make_unique<Child>(std::vector<std::string>{TALLY_SERVER_BIN, "--listen", "127.0.0.1:0", "--data-dir",
                                                            (dir / "data").string(), "--port-file",
                                                            (dir / "port").string(), "--workers", "2"},
                                   dir / "server.log");
    const auto end = std::chrono::steady_clock::now() + 20s;
    while (!fs::exists(dir / "port")) {
      if (std::chrono::steady_clock::now() > end || proc->wait(10ms)) {
        throw std::runtime_error("tally-server did not start:\n" + proc->log());
      }
    }
    std::ifstream(dir / "port") >> port;
  }
  ~Server() {
    proc->terminate();
    std::error_code ec;
    fs::remove_all(dir, ec);
  }
  std::string url() const { return fmt::format("http://127.0.0.1:{}", port); }
  HttpClient client() const { return HttpClient(*parse_http_url(url())); }
};

json example_spec() {
  std::ifstream in(fs::path(TALLY_SOURCE_DIR) / "examples" / "preview_image.json");
  return json::parse(in);
}

std::string submit(const Server& s, const json& spec) {
  HttpClient c = s.client();
  const ClientResponse r = c.request("POST", "/v1/jobs", spec.dump(), {{"Content-Type", "application/json"}});
  if (r.status != 202) throw std::runtime_error(fmt::format("submit answered {}: {}", r.status, r.body));
  return json::parse(r.body).at("id").get<std::string>();
}

json status(const Server& s, const std::string& id) {
  HttpClient c = s.client();
  return json::parse(c.request("GET", "/v1/jobs/" + id).body);
}

// The image the packets of one connection leave in tev: 7 planes by channel name.
struct Mirror {
  int width = 0, height = 0;
  std::map<std::string, std::vector<float>> planes;
  int creates = 0, updates = 0, overlays = 0, overlays_with_rects = 0;
  bool last_overlay_empty = false;
};

Mirror replay(const std::string& bytes, const std::string& name) {
  Mirror m;
  const auto packets = test::decode_tev_stream(bytes);
  for (size_t i = 0; i < packets.size(); ++i) {
    const auto& p = packets[i];
    EXPECT_EQ(p.name, name);
    if (p.type == 4) {
      EXPECT_EQ(i, 0u) << "CreateImage comes first, once per connection";
      ++m.creates;
      m.width = p.width;
      m.height = p.height;
      EXPECT_EQ(p.channels, tev::bridge_channels());
      for (const auto& c : p.channels) m.planes[c].assign(static_cast<size_t>(p.width * p.height), 0.0f);
    } else if (p.type == 6) {
      ++m.updates;
      EXPECT_FALSE(p.grab_focus);
      EXPECT_EQ(p.channels, tev::bridge_channels()) << "all channels of a tile in one packet";
      EXPECT_GE(p.x, 0);
      EXPECT_GE(p.y, 0);
      EXPECT_LE(p.x + p.w, m.width);
      EXPECT_LE(p.y + p.h, m.height);
      for (size_t c = 0; c < p.channels.size(); ++c) {
        auto& plane = m.planes[p.channels[c]];
        for (int yy = 0; yy < p.h; ++yy) {
          for (int xx = 0; xx < p.w; ++xx) {
            const int64_t px = xx + yy * p.w;
            plane[static_cast<size_t>((p.y + yy) * m.width + p.x + xx)] =
                p.data.at(static_cast<size_t>(p.offsets[c] + px * p.strides[c]));
          }
        }
      }
    } else if (p.type == 8) {
      ++m.overlays;
      EXPECT_FALSE(p.append);
      bool rect = false;
      for (const auto& c : p.commands) rect = rect || c.type == tev::kRect;
      m.overlays_with_rects += rect;
      m.last_overlay_empty = p.commands.empty();
    } else {
      ADD_FAILURE() << "unexpected packet type " << int(p.type);
    }
  }
  return m;
}

// Compares the mirror with the server's EXR of the same state, channels by name.
void expect_matches_exr(const Mirror& m, const Server& s, const std::string& id) {
  HttpClient c = s.client();
  const ClientResponse r = c.request("GET", "/v1/jobs/" + id + "/image.exr");
  ASSERT_EQ(r.status, 200) << r.body;
  const fs::path dir = temp_dir("tev-exr");
  const fs::path file = dir / "image.exr";
  std::ofstream(file, std::ios::binary) << r.body;
  auto in = OIIO::ImageInput::open(file.string());
  ASSERT_TRUE(in) << OIIO::geterror();
  const OIIO::ImageSpec& spec = in->spec();
  ASSERT_EQ(spec.width, m.width);
  ASSERT_EQ(spec.height, m.height);
  std::vector<float> all(static_cast<size_t>(spec.width * spec.height * spec.nchannels));
  ASSERT_TRUE(in->read_image(0, 0, 0, spec.nchannels, OIIO::TypeDesc::FLOAT, all.data()));
  in->close();
  for (const std::string& name : tev::bridge_channels()) {
    const int ci = spec.channelindex(name);
    ASSERT_GE(ci, 0) << "EXR has no channel " << name;
    const auto& plane = m.planes.at(name);
    size_t mismatches = 0;
    for (int i = 0; i < spec.width * spec.height; ++i) {
      const float want = all[static_cast<size_t>(i * spec.nchannels + ci)];
      const float got = plane[static_cast<size_t>(i)];
      const bool same = (std::isnan(want) && std::isnan(got)) || std::memcmp(&want, &got, 4) == 0;
      if (!same && mismatches++ < 5) ADD_FAILURE() << name << " pixel " << i << ": tev " << got << ", EXR " << want;
    }
    EXPECT_EQ(mismatches, 0u) << name;
  }
  fs::remove_all(dir);
}

std::vector<std::string> preview_argv(const Server& s, const std::string& id, uint16_t tev_port) {
  return {TALLY_CLI_BIN, "preview", id, "--tev", fmt::format("127.0.0.1:{}", tev_port), "--server", s.url()};
}

TEST(TevBridgeEndToEnd, MirrorsTheJobBitExactlyIntoTev) {
  Server server;
  FakeTev tev;
  json spec = example_spec();
  spec["stop"] = {{"max_samples", 48}};  // samples per pixel: 6 passes of 8
  const std::string id = submit(server, spec);
  const fs::path dir = temp_dir("tev-cli");
  Child cli(preview_argv(server, id, tev.port()), dir / "preview.log");
  const auto rc = cli.wait(120s);
  ASSERT_TRUE(rc.has_value()) << "tally preview did not finish:\n" << cli.log();
  EXPECT_EQ(*rc, 0) << cli.log();
  const json st = status(server, id);
  ASSERT_EQ(st.at("state"), "succeeded");

  // The bridge disconnected cleanly (shutdown, then EOF seen by tev).
  for (int i = 0; i < 100 && tev.eofs() == 0; ++i) std::this_thread::sleep_for(20ms);
  EXPECT_EQ(tev.eofs(), 1u);
  const auto conns = tev.connections();
  ASSERT_EQ(conns.size(), 1u);
  const Mirror m = replay(conns[0], "tally-" + id);
  EXPECT_EQ(m.creates, 1);
  EXPECT_GE(m.updates, 12) << "every tile at least once";
  EXPECT_TRUE(m.last_overlay_empty) << "the overlay is cleared when the job ends";
  expect_matches_exr(m, server, id);
  fs::remove_all(dir);
}

TEST(TevBridgeEndToEnd, MirrorsAJobWhosePassesAnnounceTilesTogether) {
  // 160x120 in tiles of 8: 300 tiles, so each pass publishes one `tiles` event (over 64
  // tiles) and the bridge's flushes are capped at 256 tiles (the rest in the next one).
  Server server;
  FakeTev tev;
  json spec = example_spec();
  spec["scene"]["camera"]["resolution"] = {160, 120};
  spec["query"]["tile_size"] = 8;
  // It runs until cancelled, after the bridge has mirrored it and the job has gone on
  // for two more passes: those passes reach the bridge only through `tiles` events
  // (the tiles it fetched at the start are stale by then).
  spec["query"]["max_pass_spp"] = 2;
  spec["stop"] = {{"max_samples", uint64_t{100000000}}};
  const std::string id = submit(server, spec);
  const fs::path dir = temp_dir("tev-cli");
  Child cli(preview_argv(server, id, tev.port()), dir / "preview.log");
  const auto t0 = std::chrono::steady_clock::now();
  while (tev.bytes() < 100000 && std::chrono::steady_clock::now() - t0 < 60s) std::this_thread::sleep_for(10ms);
  ASSERT_GE(tev.bytes(), 100000u) << cli.log();
  const uint64_t passes = status(server, id).at("passes").get<uint64_t>();
  while (status(server, id).at("passes").get<uint64_t>() < passes + 2 && std::chrono::steady_clock::now() - t0 < 90s) {
    std::this_thread::sleep_for(20ms);
  }
  HttpClient c = server.client();
  ASSERT_EQ(c.request("DELETE", "/v1/jobs/" + id).status / 100, 2);
  const auto rc = cli.wait(120s);
  ASSERT_TRUE(rc.has_value()) << "tally preview did not finish:\n" << cli.log();
  EXPECT_EQ(*rc, 0) << cli.log();
  ASSERT_EQ(status(server, id).at("state"), "cancelled");
  for (int i = 0; i < 100 && tev.eofs() == 0; ++i) std::this_thread::sleep_for(20ms);
  const auto conns = tev.connections();
  ASSERT_EQ(conns.size(), 1u);
  const Mirror m = replay(conns[0], "tally-" + id);
  EXPECT_EQ(m.width, 160);
  EXPECT_EQ(m.height, 120);
  EXPECT_GE(m.updates, 300) << "every tile at least once";
  expect_matches_exr(m, server, id);
  fs::remove_all(dir);
}

TEST(TevBridgeEndToEnd, ReconnectsWhenTevRestartsAndResendsTheImage) {
  Server server;
  auto tev = std::make_unique<FakeTev>();
  const uint16_t port = tev->port();
  json spec = example_spec();
  spec["seed"] = 3;
  spec["query"]["max_pass_spp"] = 2;
  // Runs until the test cancels it, after the restarted tev has been reached: a job
  // that ended on its own (a time budget) could end before tev quit on a loaded
  // machine, and then there was nothing to reconnect for.
  spec["stop"] = {{"max_samples", uint64_t{100000000}}};
  const std::string id = submit(server, spec);
  const fs::path dir = temp_dir("tev-cli");
  Child cli(preview_argv(server, id, port), dir / "preview.log");

  // Let some tiles arrive, then "quit tev" and start it again on the same port.
  const auto wait_bytes = [](const FakeTev& t, size_t n) {
    const auto t0 = std::chrono::steady_clock::now();
    while (t.bytes() < n && std::chrono::steady_clock::now() - t0 < 60s) std::this_thread::sleep_for(10ms);
    return t.bytes() >= n;
  };
  ASSERT_TRUE(wait_bytes(*tev, 20000)) << cli.log();
  const auto first = tev->connections();
  tev->stop();
  tev.reset();
  std::this_thread::sleep_for(400ms);  // the bridge's sends fail meanwhile: it backs off and retries
  auto restarted = std::make_unique<FakeTev>(port);
  ASSERT_TRUE(wait_bytes(*restarted, 1)) << cli.log();
  EXPECT_EQ(status(server, id).at("state"), "running") << "the job ran through the restart";
  HttpClient c = server.client();
  const ClientResponse cancel = c.request("DELETE", "/v1/jobs/" + id);
  ASSERT_EQ(cancel.status / 100, 2) << cancel.body;

  const auto rc = cli.wait(120s);
  ASSERT_TRUE(rc.has_value()) << "tally preview did not finish:\n" << cli.log();
  EXPECT_EQ(*rc, 0) << cli.log();
  // At least one reconnect: the restarted tev may refuse or drop the bridge's first
  // attempt while it comes up (a loaded machine counted 2), so the count is not exact.
  {
    const std::string log = cli.log();
    const size_t at = log.find(" tev reconnects");
    ASSERT_NE(at, std::string::npos) << log;
    size_t from = at;
    while (from > 0 && std::isdigit(static_cast<unsigned char>(log[from - 1]))) --from;
    ASSERT_LT(from, at) << log;
    EXPECT_GE(std::stoi(log.substr(from, at - from)), 1) << log;
  }
  for (int i = 0; i < 500 && status(server, id).at("state") == "running"; ++i) std::this_thread::sleep_for(20ms);
  ASSERT_EQ(status(server, id).at("state"), "cancelled");

  for (int i = 0; i < 100 && restarted->eofs() == 0; ++i) std::this_thread::sleep_for(20ms);
  const auto conns = restarted->connections();
  ASSERT_EQ(conns.size(), 1u);
  ASSERT_FALSE(first.empty());
  // The first tev got a well-formed prefix (a packet may be cut where it quit).
  EXPECT_EQ(static_cast<uint8_t>(first[0].at(4)), 4) << "a CreateImage first";
  // The restarted tev got the whole image again, from a new CreateImage, and every
  // tile of the final (cancelled) state: the mirror equals the server's EXR.
  const Mirror m = replay(conns[0], "tally-" + id);
  EXPECT_EQ(m.creates, 1);
  expect_matches_exr(m, server, id);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace tally
