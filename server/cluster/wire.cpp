#include "server/cluster/wire.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <bit>

#include <openssl/evp.h>

#include "common/engine/byte_codec.hpp"

namespace tally::cluster {

namespace {

// 2: BlockResult::aux (adaptive kernels); 3: as many counters as the kernel declares
// (Kernel::counter_names), no longer a fixed list; 4: compact tallies (below).
constexpr unsigned char kResultVersion = 4;

using Writer = ByteWriter;

// A short input names what it is ("result is truncated at byte N").
class Reader : public ByteReader<WireError> {
 public:
  explicit Reader(std::string_view in) : ByteReader<WireError>(in, "result") {}

  uint64_t varint() {
    uint64_t v = 0;
    for (int shift = 0; shift < 64; shift += 7) {
      const uint8_t b = u8();
      if (shift == 63 && b > 1) break;
      v |= static_cast<uint64_t>(b & 0x7f) << shift;
      if ((b & 0x80) == 0) return v;
    }
    throw WireError(fmt::format("result: a varint overflows 64 bits before byte {}", pos()));
  }
  // The compact tally written by put_tally.
  Tally tally_compact() {
    const uint8_t head = u8();
    Tally t;
    t.n = head >> 2;
    if (t.n == kBigN) {
      const uint64_t more = varint();
      if (more > UINT64_MAX - kBigN) throw WireError("result: a tally's count overflows 64 bits");
      t.n = kBigN + more;
    }
    if (head & 1) t.mean = f64();
    if (head & 2) t.m2 = f64();
    return t;
  }
  static constexpr uint64_t kBigN = 63;
};

// Image jobs send one tally per pixel channel per block: most of them have n of 0, 1 or 2
// and an M2 of exactly +0 (a single sample), so a result is mostly zero bytes. A tally is
// one head byte (bit 0: mean follows, bit 1: M2 follows, bits 2-7: n, 63 = 63 + a LEB128
// varint), then the doubles whose bits are not all zero, as raw bits: the decoded tally is
// bit-identical (a +0.0 left out decodes as +0.0; -0.0 has a bit set and travels).
void put_u64(std::string& out, uint64_t v) {
  char b[8];
  for (int i = 0; i < 8; ++i) b[i] = static_cast<char>((v >> (8 * i)) & 0xff);
  out.append(b, 8);
}
void put_tally(std::string& out, const Tally& t) {
  const uint64_t mean = std::bit_cast<uint64_t>(t.mean), m2 = std::bit_cast<uint64_t>(t.m2);
  const uint64_t small = std::min<uint64_t>(t.n, Reader::kBigN);
  out.push_back(static_cast<char>((small << 2) | (m2 != 0 ? 2u : 0u) | (mean != 0 ? 1u : 0u)));
  if (small == Reader::kBigN) {
    for (uint64_t v = t.n - Reader::kBigN;; v >>= 7) {
      if (v < 0x80) {
        out.push_back(static_cast<char>(v));
        break;
      }
      out.push_back(static_cast<char>((v & 0x7f) | 0x80));
    }
  }
  if (mean != 0) put_u64(out, mean);
  if (m2 != 0) put_u64(out, m2);
}

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
  std::string tallies;
  tallies.reserve(res.tallies.size() * 10);
  for (const Tally& t : res.tallies) put_tally(tallies, t);
  w.raw(tallies);
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
  res.tallies.resize(r.count(1));
  for (Tally& t : res.tallies) t = r.tally_compact();
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

namespace tally::cluster {

std::string result_digest(std::string_view encoded) {
  unsigned char md[EVP_MAX_MD_SIZE];
  unsigned int len = 0;
  if (EVP_Digest(encoded.data(), encoded.size(), md, &len, EVP_sha1(), nullptr) != 1) {
    throw std::runtime_error("SHA-1 of a result failed (OpenSSL)");
  }
  static constexpr char kHex[] = "0123456789abcdef";
  std::string out(2 * len, '0');
  for (unsigned i = 0; i < len; ++i) {
    out[2 * i] = kHex[md[i] >> 4];
    out[2 * i + 1] = kHex[md[i] & 15];
  }
  return out;
}

}  // namespace tally::cluster
