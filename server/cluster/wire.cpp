#include "server/cluster/wire.hpp"

#include <fmt/format.h>

#include <bit>

#include "common/engine/byte_codec.hpp"

namespace tally::cluster {

namespace {

// 2: BlockResult::aux (adaptive kernels); 3: as many counters as the kernel declares
// (Kernel::counter_names), no longer a fixed list.
constexpr unsigned char kResultVersion = 3;

using Writer = ByteWriter;

// A short input names what it is ("result is truncated at byte N").
class Reader : public ByteReader<WireError> {
 public:
  explicit Reader(std::string_view in) : ByteReader<WireError>(in, "result") {}
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
  for (const Tally& t : res.tallies) w.tally(t);
  w.u64(res.counters.values.size());
  for (uint64_t v : res.counters.values) w.u64(v);
  w.tail(res.tail);  // heap order: assign() rebuilds the same layout
  w.weights(res.weights);
  w.u8(res.fault ? 1 : 0);
  if (res.fault) w.fault(*res.fault);
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
  for (Tally& t : res.tallies) t = r.tally();
  const uint64_t nc = r.count(8);
  if (nc > Counters::kMaxCounters) throw WireError(fmt::format("{} counters (at most {})", nc, Counters::kMaxCounters));
  res.counters.values.resize(nc);
  for (auto& v : res.counters.values) v = r.u64();
  res.tail = r.tail();
  res.weights = r.weights();
  if (r.u8() != 0) res.fault = r.fault();
  res.aux.resize(r.count(8));
  for (double& v : res.aux) v = r.f64();
  if (!r.done()) throw WireError("trailing bytes after a result");
  return res;
}

}  // namespace tally::cluster
