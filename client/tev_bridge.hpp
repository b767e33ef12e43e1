#pragma once
// Mirrors a job's image into a running tev viewer (the protocol is summarised in
// docs/preview.md): one CreateImage, then an UpdateImage v3 packet per changed tile
// carrying R, G, B, StdErr.R, StdErr.G, StdErr.B and SampleCount, and a
// VectorGraphics overlay outlining the tiles still refining with their sample
// counts. tev never answers, so a broken connection shows only as a failed send:
// the bridge then reconnects (bounded retries with backoff) and re-sends the whole
// image, because a restarted tev has forgotten it.
#include <chrono>
#include <cstdint>
#include <functional>
#include <map>
#include <span>
#include <string>
#include <string_view>
#include <vector>

namespace tally {

namespace tev {

// Packet types (the first byte after the length).
enum PacketType : uint8_t {
  kCloseImage = 2,
  kCreateImage = 4,
  kUpdateImageV3 = 6,
  kVectorGraphics = 8,
};

// VectorGraphics command types used by the bridge (with their float-argument counts).
enum VgType : int8_t {
  kSave = 0, kRestore = 1, kFillColor = 2, kFill = 3, kStrokeColor = 4, kStroke = 5, kBeginPath = 6,
  kClosePath = 7, kMoveTo = 10, kLineTo = 11, kRect = 18, kText = 21, kTextAlign = 22, kFontSize = 24,
  kStrokeWidth = 25,
};
// Float arguments of a command type (-1: unknown type).
int vg_arg_count(int8_t type);

struct VgCommand {
  int8_t type = 0;
  std::vector<float> args;
  std::string text;  // Text and FontFace only
};

// Packet encoders: the bytes of one whole packet, length prefix included.
std::string create_image(std::string_view name, bool grab_focus, int32_t width, int32_t height,
                         const std::vector<std::string>& channels);
// `data` holds channel c of pixel px = (X - x) + (Y - y) * w at data[offsets[c] + px * strides[c]].
std::string update_image_v3(std::string_view name, bool grab_focus, const std::vector<std::string>& channels,
                            int32_t x, int32_t y, int32_t w, int32_t h, const std::vector<int64_t>& offsets,
                            const std::vector<int64_t>& strides, std::span<const float> data);
std::string close_image(std::string_view name);
std::string vector_graphics(std::string_view name, bool grab_focus, bool append, const std::vector<VgCommand>& cmds);

// The channels the bridge sends, in this order, interleaved per pixel.
const std::vector<std::string>& bridge_channels();

// A blocking TCP connection to tev: sends never raise SIGPIPE and time out.
class Connection {
 public:
  Connection() = default;
  ~Connection();
  Connection(const Connection&) = delete;
  Connection& operator=(const Connection&) = delete;

  // Throws std::runtime_error when the connection cannot be made.
  void open(const std::string& host, const std::string& port, double timeout_s);
  // False when the peer is gone (the connection is then closed).
  bool send(std::string_view bytes);
  // Clean shutdown: SHUT_WR, then read until EOF (bounded by `timeout_s`).
  void close(double timeout_s = 1.0);
  bool is_open() const { return fd_ >= 0; }

 private:
  int fd_ = -1;
  double timeout_s_ = 5.0;
};

}  // namespace tev

// One tile of the job's image as the server's GET /v1/jobs/{id}/tiles/{n} gives it.
struct TilePixels {
  uint32_t tile = 0;
  int x = 0, y = 0, w = 0, h = 0;
  uint64_t pass = 0;
  std::vector<float> mean;       // 3 * w * h
  std::vector<float> std_error;  // 3 * w * h
  std::vector<float> samples;    // w * h
};

struct TevBridgeOptions {
  std::string host = "127.0.0.1";
  std::string port = "14158";
  std::string image_name;         // as tev shows it, e.g. "tally-<job id>"
  int max_retries = 6;            // reconnect attempts per failure before giving up
  double initial_backoff_s = 0.25;
  double max_backoff_s = 4.0;
  double send_timeout_s = 5.0;
  bool grab_focus = true;         // on the CreateImage only
  // Sleeps between reconnect attempts (tests may shorten it).
  std::function<void(double)> sleep = nullptr;
};

// Keeps the latest pixels of every tile and mirrors them into tev.
class TevBridge {
 public:
  explicit TevBridge(TevBridgeOptions options);
  ~TevBridge();

  // Sets the image size; (re)creates the image in tev. Throws std::runtime_error
  // when tev cannot be reached after the retries.
  void begin(int width, int height);
  // A tile's new pixels: stored and sent as one UpdateImage v3 packet.
  void update_tile(const TilePixels& tile);
  // Tiles still refining (refined in the latest pass), outlined with their
  // samples per pixel; an empty list clears the overlay.
  void set_refining(const std::vector<uint32_t>& tiles);
  // Clears the overlay and closes the connection cleanly.
  void finish();

  int reconnects() const { return reconnects_; }
  uint64_t packets_sent() const { return packets_; }

 private:
  void send(const std::string& packet);      // reconnects and resends everything on failure
  void connect_with_retries();
  void send_all_locked_state();               // CreateImage + every tile + overlay
  std::string tile_packet(const TilePixels& t) const;
  std::string overlay_packet() const;

  TevBridgeOptions opt_;
  tev::Connection conn_;
  int width_ = 0, height_ = 0;
  std::map<uint32_t, TilePixels> tiles_;
  std::vector<uint32_t> refining_;
  int reconnects_ = 0;
  uint64_t packets_ = 0;
  bool began_ = false;
};

}  // namespace tally
