#include "client/tev_bridge.hpp"

#include <fmt/format.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <stdexcept>
#include <thread>

namespace tally {

namespace tev {

namespace {

// Little-endian writers (the protocol has no padding).
class Writer {
 public:
  Writer() { out_.resize(4); }  // the length, patched in finish()
  void u8(uint8_t v) { out_.push_back(static_cast<char>(v)); }
  void boolean(bool v) { u8(v ? 1 : 0); }
  void i32(int32_t v) { raw(static_cast<uint32_t>(v), 4); }
  void i64(int64_t v) { raw(static_cast<uint64_t>(v), 8); }
  void f32(float v) {
    uint32_t bits;
    std::memcpy(&bits, &v, 4);
    raw(bits, 4);
  }
  void str(std::string_view s) {
    if (s.find('\0') != std::string_view::npos) throw std::invalid_argument("tev strings cannot contain NUL");
    out_.append(s);
    out_.push_back('\0');
  }
  std::string finish() {
    const auto n = static_cast<uint32_t>(out_.size());
    for (int i = 0; i < 4; ++i) out_[i] = static_cast<char>((n >> (8 * i)) & 0xff);
    return std::move(out_);
  }

 private:
  void raw(uint64_t v, int bytes) {
    for (int i = 0; i < bytes; ++i) out_.push_back(static_cast<char>((v >> (8 * i)) & 0xff));
  }
  std::string out_;
};

}  // namespace

int vg_arg_count(int8_t type) {
  switch (type) {
    case 0: case 1: case 3: case 5: case 6: case 7: case 23: return 0;
    case 8: case 22: return 1;
    case 10: case 11: case 24: case 25: case 21: return 2;
    case 15: return 3;
    case 2: case 4: case 16: case 17: case 18: return 4;
    case 12: case 19: return 5;
    case 13: case 14: return 6;
    case 20: return 8;
    default: return -1;
  }
}

std::string create_image(std::string_view name, bool grab_focus, int32_t width, int32_t height,
                         const std::vector<std::string>& channels) {
  Writer w;
  w.u8(kCreateImage);
  w.boolean(grab_focus);
  w.str(name);
  w.i32(width);
  w.i32(height);
  w.i32(static_cast<int32_t>(channels.size()));
  for (const auto& c : channels) w.str(c);
  return w.finish();
}

std::string update_image_v3(std::string_view name, bool grab_focus, const std::vector<std::string>& channels,
                            int32_t x, int32_t y, int32_t w, int32_t h, const std::vector<int64_t>& offsets,
                            const std::vector<int64_t>& strides, std::span<const float> data) {
  if (offsets.size() != channels.size() || strides.size() != channels.size()) {
    throw std::invalid_argument("update_image_v3: one offset and one stride per channel");
  }
  // Every addressed float must exist: a short packet would desynchronise tev's reader.
  const int64_t px = static_cast<int64_t>(w) * h;
  for (size_t c = 0; c < channels.size(); ++c) {
    if (px > 0 && (offsets[c] < 0 || offsets[c] + (px - 1) * strides[c] >= static_cast<int64_t>(data.size()))) {
      throw std::invalid_argument(fmt::format("update_image_v3: channel {} reads past the data", channels[c]));
    }
  }
  Writer wr;
  wr.u8(kUpdateImageV3);
  wr.boolean(grab_focus);
  wr.str(name);
  wr.i32(static_cast<int32_t>(channels.size()));
  for (const auto& c : channels) wr.str(c);
  wr.i32(x);
  wr.i32(y);
  wr.i32(w);
  wr.i32(h);
  for (int64_t o : offsets) wr.i64(o);
  for (int64_t s : strides) wr.i64(s);
  for (float v : data) wr.f32(v);
  return wr.finish();
}

std::string close_image(std::string_view name) {
  Writer w;
  w.u8(kCloseImage);
  w.str(name);
  return w.finish();
}

std::string vector_graphics(std::string_view name, bool grab_focus, bool append, const std::vector<VgCommand>& cmds) {
  Writer w;
  w.u8(kVectorGraphics);
  w.boolean(grab_focus);
  w.str(name);
  w.boolean(append);
  w.i32(static_cast<int32_t>(cmds.size()));
  for (const VgCommand& c : cmds) {
    const int n = vg_arg_count(c.type);
    if (n < 0 || static_cast<size_t>(n) != c.args.size()) {
      throw std::invalid_argument(fmt::format("vector graphics command {} takes {} arguments, got {}", c.type, n,
                                              c.args.size()));
    }
    w.u8(static_cast<uint8_t>(c.type));
    for (float a : c.args) w.f32(a);
    if (c.type == kText || c.type == 23) w.str(c.text);
  }
  return w.finish();
}

const std::vector<std::string>& bridge_channels() {
  static const std::vector<std::string> ch = {"R", "G", "B", "StdErr.R", "StdErr.G", "StdErr.B", "SampleCount"};
  return ch;
}

// ---------------------------------------------------------------- Connection

Connection::~Connection() {
  if (fd_ >= 0) ::close(fd_);
}

void Connection::open(const std::string& host, const std::string& port, double timeout_s) {
  close(0.0);
  timeout_s_ = timeout_s;
  addrinfo hints{};
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  addrinfo* res = nullptr;
  if (const int rc = ::getaddrinfo(host.c_str(), port.c_str(), &hints, &res); rc != 0) {
    throw std::runtime_error(fmt::format("tev at {}:{}: {}", host, port, ::gai_strerror(rc)));
  }
  std::string last_error = "no address";
  for (addrinfo* a = res; a; a = a->ai_next) {
    const int fd = ::socket(a->ai_family, a->ai_socktype | SOCK_CLOEXEC, a->ai_protocol);
    if (fd < 0) continue;
    timeval tv{};
    tv.tv_sec = static_cast<time_t>(timeout_s);
    tv.tv_usec = static_cast<suseconds_t>((timeout_s - std::floor(timeout_s)) * 1e6);
    ::setsockopt(fd, SOL_SOCKET, SO_SNDTIMEO, &tv, sizeof tv);
    ::setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
    const int one = 1;
    ::setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
    if (::connect(fd, a->ai_addr, a->ai_addrlen) == 0) {
      fd_ = fd;
      break;
    }
    last_error = std::strerror(errno);
    ::close(fd);
  }
  ::freeaddrinfo(res);
  if (fd_ < 0) throw std::runtime_error(fmt::format("cannot connect to tev at {}:{}: {}", host, port, last_error));
}

bool Connection::send(std::string_view bytes) {
  if (fd_ < 0) return false;
  // tev never writes; anything readable on the socket is its EOF or a reset, i.e. gone.
  pollfd p{fd_, POLLIN, 0};
  if (::poll(&p, 1, 0) > 0 && (p.revents & (POLLIN | POLLHUP | POLLERR))) {
    char buf[256];
    const ssize_t n = ::recv(fd_, buf, sizeof buf, MSG_DONTWAIT);
    if (n <= 0) {
      ::close(fd_);
      fd_ = -1;
      return false;
    }
  }
  while (!bytes.empty()) {
    const ssize_t n = ::send(fd_, bytes.data(), bytes.size(), MSG_NOSIGNAL);
    if (n < 0) {
      if (errno == EINTR) continue;
      ::close(fd_);
      fd_ = -1;
      return false;
    }
    bytes.remove_prefix(static_cast<size_t>(n));
  }
  return true;
}

void Connection::close(double timeout_s) {
  if (fd_ < 0) return;
  if (timeout_s > 0) {
    ::shutdown(fd_, SHUT_WR);
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
    char buf[256];
    while (std::chrono::steady_clock::now() < deadline) {
      pollfd p{fd_, POLLIN, 0};
      const int left_ms = static_cast<int>(
          std::chrono::duration<double, std::milli>(deadline - std::chrono::steady_clock::now()).count());
      if (::poll(&p, 1, std::max(left_ms, 1)) <= 0) break;
      if (::recv(fd_, buf, sizeof buf, 0) <= 0) break;  // EOF (or error): tev has closed its side
    }
  }
  ::close(fd_);
  fd_ = -1;
}

}  // namespace tev

// ---------------------------------------------------------------- TevBridge

TevBridge::TevBridge(TevBridgeOptions options) : opt_(std::move(options)) {
  if (!opt_.sleep) {
    opt_.sleep = [](double s) { std::this_thread::sleep_for(std::chrono::duration<double>(s)); };
  }
}

TevBridge::~TevBridge() { conn_.close(0.0); }

void TevBridge::begin(int width, int height) {
  width_ = width;
  height_ = height;
  began_ = true;
  tiles_.clear();
  refining_.clear();
  if (!conn_.is_open()) {
    connect_with_retries();  // sends the CreateImage
    return;
  }
  send(tev::create_image(opt_.image_name, opt_.grab_focus, width_, height_, tev::bridge_channels()));
}

std::string TevBridge::tile_packet(const TilePixels& t) const {
  const size_t px = static_cast<size_t>(t.w) * static_cast<size_t>(t.h);
  // Interleaved R G B SR SG SB N: offsets 0..6, stride 7, one packet per tile.
  std::vector<float> data(7 * px);
  for (size_t i = 0; i < px; ++i) {
    for (int c = 0; c < 3; ++c) {
      data[7 * i + c] = t.mean[3 * i + c];
      data[7 * i + 3 + c] = t.std_error[3 * i + c];
    }
    data[7 * i + 6] = t.samples[i];
  }
  return tev::update_image_v3(opt_.image_name, false, tev::bridge_channels(), t.x, t.y, t.w, t.h,
                              {0, 1, 2, 3, 4, 5, 6}, {7, 7, 7, 7, 7, 7, 7}, data);
}

std::string TevBridge::overlay_packet() const {
  std::vector<tev::VgCommand> cmds;
  if (!refining_.empty()) {
    cmds.push_back({tev::kSave, {}, {}});
    cmds.push_back({tev::kStrokeColor, {1.0f, 0.75f, 0.1f, 0.9f}, {}});
    for (uint32_t n : refining_) {
      const auto it = tiles_.find(n);
      if (it == tiles_.end()) continue;
      const TilePixels& t = it->second;
      cmds.push_back({tev::kBeginPath, {}, {}});
      cmds.push_back({tev::kRect,
                      {static_cast<float>(t.x) + 0.5f, static_cast<float>(t.y) + 0.5f, static_cast<float>(t.w) - 1.0f,
                       static_cast<float>(t.h) - 1.0f},
                      {}});
      cmds.push_back({tev::kStroke, {}, {}});
    }
    cmds.push_back({tev::kFillColor, {1.0f, 0.85f, 0.3f, 1.0f}, {}});
    for (uint32_t n : refining_) {
      const auto it = tiles_.find(n);
      if (it == tiles_.end()) continue;
      const TilePixels& t = it->second;
      double sum = 0;
      for (float s : t.samples) sum += static_cast<double>(s);
      const double spp = t.samples.empty() ? 0.0 : sum / static_cast<double>(t.samples.size());
      cmds.push_back({tev::kText, {static_cast<float>(t.x) + 2.0f, static_cast<float>(t.y) + 10.0f},
                      fmt::format("{:.0f} spp", spp)});
    }
    cmds.push_back({tev::kRestore, {}, {}});
  }
  return tev::vector_graphics(opt_.image_name, false, false, cmds);
}

void TevBridge::update_tile(const TilePixels& tile) {
  if (tile.mean.size() != 3 * static_cast<size_t>(tile.w) * static_cast<size_t>(tile.h) ||
      tile.std_error.size() != tile.mean.size() || tile.samples.size() * 3 != tile.mean.size()) {
    throw std::runtime_error(fmt::format("tile {}: pixel arrays do not match its {}x{} size", tile.tile, tile.w, tile.h));
  }
  tiles_[tile.tile] = tile;
  send(tile_packet(tile));
}

void TevBridge::set_refining(const std::vector<uint32_t>& tiles) {
  if (tiles == refining_ && !tiles.empty()) return;
  refining_ = tiles;
  send(overlay_packet());
}

void TevBridge::finish() {
  if (conn_.is_open()) {
    refining_.clear();
    conn_.send(overlay_packet());
  }
  conn_.close(1.0);
}

void TevBridge::send(const std::string& packet) {
  if (conn_.is_open() && conn_.send(packet)) {
    ++packets_;
    return;
  }
  // The state is stored before sending, so a full resend includes this packet.
  connect_with_retries();
}

void TevBridge::send_all_locked_state() {
  if (!conn_.send(tev::create_image(opt_.image_name, opt_.grab_focus, width_, height_, tev::bridge_channels()))) return;
  ++packets_;
  for (const auto& [n, t] : tiles_) {
    if (!conn_.send(tile_packet(t))) return;
    ++packets_;
  }
  if (!refining_.empty()) {
    if (!conn_.send(overlay_packet())) return;
    ++packets_;
  }
}

void TevBridge::connect_with_retries() {
  double backoff = opt_.initial_backoff_s;
  std::string last;
  const bool first = packets_ == 0;
  for (int attempt = 0; attempt <= opt_.max_retries; ++attempt) {
    if (attempt > 0) {
      opt_.sleep(backoff);
      backoff = std::min(backoff * 2, opt_.max_backoff_s);
    }
    try {
      conn_.open(opt_.host, opt_.port, opt_.send_timeout_s);
    } catch (const std::exception& e) {
      last = e.what();
      continue;
    }
    if (began_) send_all_locked_state();
    if (conn_.is_open()) {
      if (!first) ++reconnects_;
      return;
    }
    last = "tev closed the connection";
  }
  throw std::runtime_error(fmt::format("giving up on tev after {} attempts: {}", opt_.max_retries + 1, last));
}

}  // namespace tally
