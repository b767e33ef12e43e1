#pragma once
// An independent reader of tev's network protocol (per
// ../shared/references/tev-protocol.md), for checking what the bridge sends. It
// throws on anything malformed: a wrong length, a truncated string, an unknown
// vector-graphics command, trailing bytes.
#include <cstdint>
#include <cstring>
#include <map>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

namespace tally::test {

struct TevVg {
  int8_t type;
  std::vector<float> args;
  std::string text;
};

struct TevPacket {
  uint8_t type = 0;
  bool grab_focus = false;
  std::string name;
  // CreateImage
  int32_t width = 0, height = 0;
  std::vector<std::string> channels;  // CreateImage and UpdateImage v3
  // UpdateImage v3
  int32_t x = 0, y = 0, w = 0, h = 0;
  std::vector<int64_t> offsets, strides;
  std::vector<float> data;
  // VectorGraphics
  bool append = false;
  std::vector<TevVg> commands;
};

class TevReader {
 public:
  explicit TevReader(std::string_view b) : b_(b) {}
  bool done() const { return p_ == b_.size(); }
  size_t pos() const { return p_; }

  uint8_t u8() {
    need(1);
    return static_cast<uint8_t>(b_[p_++]);
  }
  bool boolean() {
    const uint8_t v = u8();
    if (v > 1) throw std::runtime_error("bool byte is not 0 or 1");
    return v == 1;
  }
  template <class T>
  T le() {
    need(sizeof(T));
    uint64_t v = 0;
    for (size_t i = 0; i < sizeof(T); ++i) v |= static_cast<uint64_t>(static_cast<uint8_t>(b_[p_ + i])) << (8 * i);
    p_ += sizeof(T);
    T out;
    if constexpr (sizeof(T) == 4) {
      const auto v32 = static_cast<uint32_t>(v);
      std::memcpy(&out, &v32, 4);
    } else {
      std::memcpy(&out, &v, sizeof(T));
    }
    return out;
  }
  std::string str() {
    const size_t nul = b_.find('\0', p_);
    if (nul == std::string_view::npos) throw std::runtime_error("string without NUL");
    std::string s(b_.substr(p_, nul - p_));
    p_ = nul + 1;
    return s;
  }

 private:
  void need(size_t n) const {
    if (p_ + n > b_.size()) throw std::runtime_error("packet truncated");
  }
  std::string_view b_;
  size_t p_ = 0;
};

inline int tev_vg_args(int8_t t) {
  static const std::map<int, int> n = {{0, 0},  {1, 0},  {2, 4},  {3, 0},  {4, 4},  {5, 0},  {6, 0},
                                       {7, 0},  {8, 1},  {10, 2}, {11, 2}, {12, 5}, {13, 6}, {14, 6},
                                       {15, 3}, {16, 4}, {17, 4}, {18, 4}, {19, 5}, {20, 8}, {21, 2},
                                       {22, 1}, {23, 0}, {24, 2}, {25, 2}};
  const auto it = n.find(t);
  if (it == n.end()) throw std::runtime_error("unknown vector graphics command " + std::to_string(t));
  return it->second;
}

// Splits a byte stream into packets and decodes the ones the bridge may send.
inline std::vector<TevPacket> decode_tev_stream(std::string_view bytes) {
  std::vector<TevPacket> out;
  size_t off = 0;
  while (off < bytes.size()) {
    if (bytes.size() - off < 5) throw std::runtime_error("stream ends inside a packet header");
    TevReader lenr(bytes.substr(off, 4));
    const uint32_t len = lenr.le<uint32_t>();
    if (len < 5 || off + len > bytes.size()) throw std::runtime_error("bad packet length " + std::to_string(len));
    TevReader r(bytes.substr(off + 4, len - 4));
    TevPacket p;
    p.type = r.u8();
    switch (p.type) {
      case 2:
        p.name = r.str();
        break;
      case 4: {
        p.grab_focus = r.boolean();
        p.name = r.str();
        p.width = r.le<int32_t>();
        p.height = r.le<int32_t>();
        const int32_t n = r.le<int32_t>();
        for (int32_t i = 0; i < n; ++i) p.channels.push_back(r.str());
        break;
      }
      case 6: {
        p.grab_focus = r.boolean();
        p.name = r.str();
        const int32_t n = r.le<int32_t>();
        for (int32_t i = 0; i < n; ++i) p.channels.push_back(r.str());
        p.x = r.le<int32_t>();
        p.y = r.le<int32_t>();
        p.w = r.le<int32_t>();
        p.h = r.le<int32_t>();
        for (int32_t i = 0; i < n; ++i) p.offsets.push_back(r.le<int64_t>());
        for (int32_t i = 0; i < n; ++i) p.strides.push_back(r.le<int64_t>());
        while (!r.done()) p.data.push_back(r.le<float>());
        break;
      }
      case 8: {
        p.grab_focus = r.boolean();
        p.name = r.str();
        p.append = r.boolean();
        const int32_t n = r.le<int32_t>();
        for (int32_t i = 0; i < n; ++i) {
          TevVg c;
          c.type = static_cast<int8_t>(r.u8());
          const int k = tev_vg_args(c.type);
          for (int j = 0; j < k; ++j) c.args.push_back(r.le<float>());
          if (c.type == 21 || c.type == 23) c.text = r.str();
          p.commands.push_back(std::move(c));
        }
        break;
      }
      default:
        throw std::runtime_error("unexpected packet type " + std::to_string(p.type));
    }
    if (!r.done()) throw std::runtime_error("trailing bytes in packet of type " + std::to_string(p.type));
    out.push_back(std::move(p));
    off += len;
  }
  return out;
}

}  // namespace tally::test
