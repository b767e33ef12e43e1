#include "server/cluster/wire.hpp"

#include <fmt/format.h>

#include <bit>

namespace tally::cluster {

namespace {

// 2: BlockResult::aux (adaptive kernels); 3: as many counters as the kernel declares
// (Kernel::counter_names), no longer a fixed list.
constexpr unsigned char kResultVersion = 3;

class Writer {
 public:
  void u8(unsigned char v) { out_.push_back(static_cast<char>(v)); }
  void u64(uint64_t v) {
    for (int i = 0; i < 8; ++i) out_.push_back(static_cast<char>((v >> (8 * i)) & 0xff));
  }
  void f64(double v) { u64(std::bit_cast<uint64_t>(v)); }
  void bytes(std::string_view s) {
    u64(s.size());
    out_.append(s);
  }
  std::string take() { return std::move(out_); }

 private:
  std::string out_;
};

class Reader {
 public:
  explicit Reader(std::string_view in) : in_(in) {}
  unsigned char u8() {
    need(1);
    return static_cast<unsigned char>(in_[pos_++]);
  }
  uint64_t u64() {
    need(8);
    uint64_t v = 0;
    for (int i = 0; i < 8; ++i) {
      v |= static_cast<uint64_t>(static_cast<unsigned char>(in_[pos_ + static_cast<size_t>(i)])) << (8 * i);
    }
    pos_ += 8;
    return v;
  }
  double f64() { return std::bit_cast<double>(u64()); }
  uint64_t count(size_t item_size) {
    const uint64_t n = u64();
    if (n > (in_.size() - pos_) / item_size) throw WireError(fmt::format("count {} at byte {} exceeds the input", n, pos_));
    return n;
  }
  std::string bytes() {
    const uint64_t n = count(1);
    std::string s(in_.substr(pos_, n));
    pos_ += n;
    return s;
  }
  bool done() const { return pos_ == in_.size(); }

 private:
  void need(size_t n) const {
    if (in_.size() - pos_ < n) throw WireError(fmt::format("truncated at byte {}", pos_));
  }
  std::string_view in_;
  size_t pos_ = 0;
};

}  // namespace

std::string encode_block(const Block& b) {
  Writer w;
  w.u64(b.index);
  w.u64(b.first_sample);
  w.u64(b.sample_count);
  w.u64(b.partition);
  return w.take();
}

Block decode_block(std::string_view bytes) {
  if (bytes.size() != 32) throw WireError(fmt::format("a block is 32 bytes, got {}", bytes.size()));
  Reader r(bytes);
  Block b;
  b.index = r.u64();
  b.first_sample = r.u64();
  b.sample_count = r.u64();
  const uint64_t p = r.u64();
  if (p > UINT32_MAX) throw WireError("block partition out of range");
  b.partition = static_cast<uint32_t>(p);
  return b;
}

std::vector<Block> decode_blocks(std::string_view bytes) {
  if (bytes.empty() || bytes.size() % 32 != 0) throw WireError(fmt::format("an entry of {} bytes is not whole blocks", bytes.size()));
  std::vector<Block> out;
  for (size_t i = 0; i < bytes.size(); i += 32) out.push_back(decode_block(bytes.substr(i, 32)));
  return out;
}

std::string encode_result(const BlockResult& res) {
  Writer w;
  w.u8(kResultVersion);
  w.u64(res.block_index);
  w.u64(res.first_channel);
  w.u64(res.tallies.size());
  for (const Tally& t : res.tallies) {
    w.u64(t.n);
    w.f64(t.mean);
    w.f64(t.m2);
  }
  w.u64(res.counters.values.size());
  for (uint64_t v : res.counters.values) w.u64(v);
  w.u64(res.tail.capacity());
  w.u64(res.tail.heap().size());
  for (double v : res.tail.heap()) w.f64(v);  // heap order: assign() rebuilds the same layout
  w.f64(res.weights.sum_w);
  w.f64(res.weights.sum_w2);
  w.u8(res.fault ? 1 : 0);
  if (res.fault) {
    w.u64(res.fault->sample_index);
    w.u64(res.fault->channel);
    w.f64(res.fault->value);
    w.u64(res.fault->point.size());
    for (double v : res.fault->point) w.f64(v);
    w.bytes(res.fault->message);
  }
  w.u64(res.aux.size());
  for (double v : res.aux) w.f64(v);
  return w.take();
}

BlockResult decode_result(std::string_view bytes) {
  Reader r(bytes);
  if (const unsigned v = r.u8(); v != kResultVersion) throw WireError(fmt::format("result version {} is not {}", v, kResultVersion));
  BlockResult res;
  res.block_index = r.u64();
  const uint64_t fc = r.u64();
  if (fc > UINT32_MAX) throw WireError("first_channel out of range");
  res.first_channel = static_cast<uint32_t>(fc);
  res.tallies.resize(r.count(24));
  for (Tally& t : res.tallies) {
    t.n = r.u64();
    t.mean = r.f64();
    t.m2 = r.f64();
  }
  const uint64_t nc = r.count(8);
  if (nc > Counters::kMaxCounters) throw WireError(fmt::format("{} counters (at most {})", nc, Counters::kMaxCounters));
  res.counters.values.resize(nc);
  for (auto& v : res.counters.values) v = r.u64();
  const uint64_t cap = r.u64();
  if (cap == 0 || cap > (1u << 20)) throw WireError("tail capacity out of range");
  std::vector<double> tail(r.count(8));
  if (tail.size() > cap) throw WireError("tail larger than its capacity");
  for (double& v : tail) v = r.f64();
  res.tail = TailTracker(cap);
  res.tail.assign(std::move(tail));
  res.weights.sum_w = r.f64();
  res.weights.sum_w2 = r.f64();
  if (r.u8() != 0) {
    SampleFault f;
    f.sample_index = r.u64();
    const uint64_t ch = r.u64();
    if (ch > UINT32_MAX) throw WireError("fault channel out of range");
    f.channel = static_cast<uint32_t>(ch);
    f.value = r.f64();
    f.point.resize(r.count(8));
    for (double& v : f.point) v = r.f64();
    f.message = r.bytes();
    res.fault = std::move(f);
  }
  res.aux.resize(r.count(8));
  for (double& v : res.aux) v = r.f64();
  if (!r.done()) throw WireError("trailing bytes after a result");
  return res;
}

}  // namespace tally::cluster
