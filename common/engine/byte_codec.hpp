#pragma once
// The one binary codec of engine state: checkpoints (checkpoint.cpp), the cluster
// wire format (server/cluster/wire.cpp) and adaptive kernels' own state and pass input
// (VEGAS: common/integrate/vegas.cpp) write integers, doubles, tallies, tail trackers,
// importance weights and sample faults with it, field for field the same.
// Little-endian u64, doubles as their raw bits (so what is decoded merges
// bit-identically). Readers check every length against what is left and never read
// past their input: malformed bytes throw `Error`, the caller's exception type
// (CheckpointError, WireError).
#include <algorithm>
#include <bit>
#include <cmath>
#include <functional>
#include <cstdint>
#include <fmt/format.h>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "common/engine/sample_stats.hpp"
#include "common/stats/tail_index.hpp"
#include "common/stats/tally.hpp"

namespace tally {

class ByteWriter {
 public:
  // Room for `bytes` more without reallocating (a checkpoint knows its size roughly).
  void reserve(size_t bytes) { out_.reserve(out_.size() + bytes); }
  void u8(uint8_t v) { out_.push_back(static_cast<char>(v)); }
  void u64(uint64_t v) { little_endian(v); }
  void f64(double v) { u64(std::bit_cast<uint64_t>(v)); }
  void u32(uint32_t v) { little_endian(v); }
  void f32(float v) { u32(std::bit_cast<uint32_t>(v)); }
  void raw(std::string_view s) { out_.append(s); }
  void bytes(std::string_view s) {  // length, then the bytes
    u64(s.size());
    out_.append(s);
  }
  const std::string& str() const { return out_; }
  std::string take() { return std::move(out_); }
  // Drops the first `n` bytes written (a writer that hands its output on in pieces).
  void drop_front(size_t n) { out_.erase(0, n); }

  // n, mean, M2
  void tally(const Tally& t) {
    u64(t.n);
    f64(t.mean);
    f64(t.m2);
  }
  // capacity, then the heap in its own order (TailTracker::assign rebuilds that layout)
  void tail(const TailTracker& t) {
    u64(t.capacity());
    u64(t.heap().size());
    for (double v : t.heap()) f64(v);
  }
  void weights(const WeightStats& w) {
    f64(w.sum_w);
    f64(w.sum_w2);
  }
  // The fault's fields (whether there is one is the caller's flag).
  void fault(const SampleFault& f) {
    u64(f.sample_index);
    u64(f.channel);
    f64(f.value);
    u64(f.point.size());
    for (double v : f.point) f64(v);
    bytes(f.message);
  }

 private:
  template <class U>
  void little_endian(U v) {
    char b[sizeof(U)];  // one append, not a push_back a byte: checkpoints write millions of these
    for (size_t i = 0; i < sizeof(U); ++i) b[i] = static_cast<char>((v >> (8 * i)) & 0xff);
    out_.append(b, sizeof(U));
  }

  std::string out_;
};

template <class Error>
class ByteReader {
 public:
  // `what` names the input in errors ("checkpoint", "result").
  ByteReader(std::string_view in, std::string_view what) : in_(in), what_(what) {}

  uint8_t u8() {
    need(1);
    return static_cast<uint8_t>(in_[pos_++]);
  }
  uint64_t u64() { return little_endian<uint64_t>(); }
  double f64() { return std::bit_cast<double>(u64()); }
  uint32_t u32() { return little_endian<uint32_t>(); }
  float f32() { return std::bit_cast<float>(u32()); }
  // A count of items of at least `item_size` bytes each, checked against what is left.
  uint64_t count(size_t item_size) {
    const uint64_t n = u64();
    if (item_size > 0 && n > (in_.size() - pos_) / item_size) {
      throw Error(fmt::format("{} is truncated or corrupt (count {} at byte {})", what_, n, pos_));
    }
    return n;
  }
  std::string bytes() {
    const uint64_t n = count(1);
    std::string s(in_.substr(pos_, n));
    pos_ += n;
    return s;
  }
  size_t pos() const { return pos_; }
  bool done() const { return pos_ == in_.size(); }

  Tally tally() {
    Tally t;
    t.n = u64();
    t.mean = f64();
    t.m2 = f64();
    return t;
  }
  TailTracker tail() {
    const uint64_t cap = u64();
    if (cap == 0 || cap > (1u << 20)) throw Error(fmt::format("{}: tail capacity {} is out of range", what_, cap));
    std::vector<double> heap(count(8));
    if (heap.size() > cap) throw Error(fmt::format("{}: tail larger than its capacity", what_));
    for (double& v : heap) {
      v = f64();
      // A tail keeps positive finite magnitudes only (TailTracker::offer drops the rest).
      if (!(v > 0.0) || !std::isfinite(v)) throw Error(fmt::format("{}: tail value {} is not a positive magnitude", what_, v));
    }
    // Stored as the tracker's min-heap: anything else would be silently reordered.
    if (!std::is_heap(heap.begin(), heap.end(), std::greater<>())) throw Error(fmt::format("{}: tail is not a heap", what_));
    TailTracker t(cap);
    t.assign(std::move(heap));
    return t;
  }
  WeightStats weights() {
    WeightStats w;
    w.sum_w = f64();
    w.sum_w2 = f64();
    return w;
  }
  SampleFault fault() {
    SampleFault f;
    f.sample_index = u64();
    const uint64_t ch = u64();
    if (ch > UINT32_MAX) throw Error(fmt::format("{}: fault channel {} is out of range", what_, ch));
    f.channel = static_cast<uint32_t>(ch);
    f.value = f64();
    f.point.resize(count(8));
    for (double& v : f.point) v = f64();
    f.message = bytes();
    return f;
  }

 private:
  template <class U>
  U little_endian() {
    need(sizeof(U));
    U v = 0;
    for (size_t i = 0; i < sizeof(U); ++i) v |= static_cast<U>(static_cast<unsigned char>(in_[pos_ + i])) << (8 * i);
    pos_ += sizeof(U);
    return v;
  }

  void need(size_t n) const {
    if (in_.size() - pos_ < n) throw Error(fmt::format("{} is truncated at byte {}", what_, pos_));
  }
  std::string_view in_;
  std::string_view what_;
  size_t pos_ = 0;
};

}  // namespace tally
