#include "server/cluster/wire.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <bit>
#include <cstring>

#include "common/engine/byte_codec.hpp"
#include "common/hash/digest.hpp"

namespace tally::cluster {

namespace {

// 2: BlockResult::aux (adaptive kernels); 3: as many counters as the kernel declares
// (Kernel::counter_names), no longer a fixed list; 4: compact tallies (below); 5: a
// tally equal to the one before it is one byte; 6: sum channels (BlockResult::sums, after
// aux, compact as below).
constexpr unsigned char kResultVersion = 6;

using Writer = ByteWriter;

// A short input names what it is ("result is truncated at byte N").
class Reader : public ByteReader<WireError> {
 public:
  explicit Reader(std::string_view in) : ByteReader<WireError>(in, "result") {}
};

// Image jobs send one tally per pixel channel per block: most of them have n of 0, 1 or 2
// and an M2 of exactly +0 (a single sample), so a result is mostly zero bytes; and in a
// grey (achromatic) scene, or wherever a pixel is black, a pixel's R, G and B tallies are
// equal bit for bit. A tally is one head byte: bits 2-7 are 0-61 (n), 62 (n is 62 + a
// LEB128 varint that follows) or 63 (kRepeat: the tally before it again; the whole byte is
// 0xfc); bit 0: mean follows, bit 1: M2 follows. The doubles whose bits are not all zero
// follow as raw little-endian bits: the decoded tally is bit-identical (a +0.0 left out
// decodes as +0.0; -0.0 has a bit set and travels). Written and read with plain
// pointers: this is the bulk of an image result.
constexpr uint64_t kBigN = 62;
constexpr unsigned char kRepeat = 63u << 2;
constexpr size_t kMaxTallyBytes = 1 + 10 + 8 + 8;

char* put_le(char* p, uint64_t v) {
  if constexpr (std::endian::native == std::endian::little) {
    std::memcpy(p, &v, 8);
  } else {
    for (int i = 0; i < 8; ++i) p[i] = static_cast<char>((v >> (8 * i)) & 0xff);
  }
  return p + 8;
}
uint64_t get_le(const char* p) {
  uint64_t v = 0;
  if constexpr (std::endian::native == std::endian::little) {
    std::memcpy(&v, p, 8);
  } else {
    for (int i = 0; i < 8; ++i) v |= static_cast<uint64_t>(static_cast<unsigned char>(p[i])) << (8 * i);
  }
  return v;
}

void put_tallies(std::string& out, const std::vector<Tally>& tallies) {
  const size_t start = out.size();
  out.resize(start + tallies.size() * kMaxTallyBytes);
  char* p = out.data() + start;
  const Tally* prev = nullptr;
  for (const Tally& t : tallies) {
    const uint64_t mean = std::bit_cast<uint64_t>(t.mean), m2 = std::bit_cast<uint64_t>(t.m2);
    if (prev && prev->n == t.n && std::bit_cast<uint64_t>(prev->mean) == mean && std::bit_cast<uint64_t>(prev->m2) == m2) {
      *p++ = static_cast<char>(kRepeat);
      continue;
    }
    prev = &t;
    const uint64_t small = std::min<uint64_t>(t.n, kBigN);
    *p++ = static_cast<char>((small << 2) | (m2 != 0 ? 2u : 0u) | (mean != 0 ? 1u : 0u));
    if (small == kBigN) {
      uint64_t v = t.n - kBigN;
      for (; v >= 0x80; v >>= 7) *p++ = static_cast<char>((v & 0x7f) | 0x80);
      *p++ = static_cast<char>(v);
    }
    if (mean != 0) p = put_le(p, mean);
    if (m2 != 0) p = put_le(p, m2);
  }
  out.resize(static_cast<size_t>(p - out.data()));
}

// Reads `tallies.size()` compact tallies from the front of `in`; returns the bytes used.
size_t get_tallies(std::string_view in, std::vector<Tally>& tallies) {
  const char* p = in.data();
  const char* const end = p + in.size();
  auto truncated = [&] {
    return WireError(fmt::format("result is truncated in tally data at byte {}", p - in.data()));
  };
  for (size_t i = 0; i < tallies.size(); ++i) {
    Tally& t = tallies[i];
    if (p == end) throw truncated();
    const auto head = static_cast<unsigned char>(*p++);
    if ((head & ~3u) == kRepeat) {
      if (head != kRepeat) throw WireError(fmt::format("result: tally head byte {:#04x} is not defined", head));
      if (i == 0) throw WireError("result: the first tally repeats the one before it");
      t = tallies[i - 1];
      continue;
    }
    t.n = head >> 2;
    if (t.n == kBigN) {
      uint64_t more = 0;
      for (int shift = 0;; shift += 7) {
        if (p == end) throw truncated();
        const auto b = static_cast<unsigned char>(*p++);
        if (shift == 63 && b > 1) throw WireError("result: a tally's count overflows 64 bits");
        more |= static_cast<uint64_t>(b & 0x7f) << shift;
        if ((b & 0x80) == 0) break;
      }
      if (more > UINT64_MAX - kBigN) throw WireError("result: a tally's count overflows 64 bits");
      t.n = kBigN + more;
    }
    const size_t doubles = (head & 1u) + ((head >> 1) & 1u);
    if (static_cast<size_t>(end - p) < 8 * doubles) throw truncated();
    t.mean = 0.0;
    t.m2 = 0.0;
    if (head & 1u) {
      t.mean = std::bit_cast<double>(get_le(p));
      p += 8;
    }
    if (head & 2u) {
      t.m2 = std::bit_cast<double>(get_le(p));
      p += 8;
    }
  }
  return static_cast<size_t>(p - in.data());
}

// Sum channels: a tag byte each, kSumZero (the bits of +0.0: a black pixel), kSumRepeat
// (the sum before it again, bit for bit: a grey pixel's G and B) or kSumLiteral followed
// by the 8 bytes of its bits. Bit-exact, like the tallies.
constexpr unsigned char kSumZero = 0, kSumRepeat = 1, kSumLiteral = 2;

void put_sums(std::string& out, const std::vector<double>& sums) {
  const size_t start = out.size();
  out.resize(start + sums.size() * 9);
  char* p = out.data() + start;
  uint64_t prev = 0;
  for (size_t i = 0; i < sums.size(); ++i) {
    const uint64_t v = std::bit_cast<uint64_t>(sums[i]);
    if (v == 0) {
      *p++ = static_cast<char>(kSumZero);
    } else if (i > 0 && v == prev) {
      *p++ = static_cast<char>(kSumRepeat);
    } else {
      *p++ = static_cast<char>(kSumLiteral);
      p = put_le(p, v);
    }
    prev = v;
  }
  out.resize(static_cast<size_t>(p - out.data()));
}

// Reads `sums.size()` compact sums from the front of `in`; returns the bytes used.
size_t get_sums(std::string_view in, std::vector<double>& sums) {
  const char* p = in.data();
  const char* const end = p + in.size();
  auto truncated = [&] { return WireError(fmt::format("result is truncated in sum data at byte {}", p - in.data())); };
  for (size_t i = 0; i < sums.size(); ++i) {
    if (p == end) throw truncated();
    const auto tag = static_cast<unsigned char>(*p++);
    if (tag == kSumZero) {
      sums[i] = 0.0;
    } else if (tag == kSumRepeat) {
      if (i == 0) throw WireError("result: the first sum repeats the one before it");
      sums[i] = sums[i - 1];
    } else if (tag == kSumLiteral) {
      if (end - p < 8) throw truncated();
      sums[i] = std::bit_cast<double>(get_le(p));
      p += 8;
    } else {
      throw WireError(fmt::format("result: sum tag byte {:#04x} is not defined", tag));
    }
  }
  return static_cast<size_t>(p - in.data());
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
  Writer head;
  head.u8(kResultVersion);
  head.u64(res.block_index);
  head.u64(res.first_channel);
  head.u64(res.tallies.size());
  std::string out = head.take();
  put_tallies(out, res.tallies);
  Writer w;
  w.u64(res.counters.values.size());
  for (uint64_t v : res.counters.values) w.u64(v);
  w.tail(res.tail);  // heap order: assign() rebuilds the same layout
  w.weights(res.weights);
  w.u8(res.fault ? 1 : 0);
  if (res.fault) w.fault(*res.fault);
  w.u64(res.aux.size());
  for (double v : res.aux) w.f64(v);
  w.u64(res.first_sum);
  w.u64(res.sums.size());
  out += w.str();
  put_sums(out, res.sums);
  return out;
}

BlockResult decode_result(std::string_view bytes) {
  Reader head(bytes);
  if (const unsigned v = head.u8(); v != kResultVersion) {
    throw WireError(fmt::format("result version {} is not {}", v, kResultVersion));
  }
  BlockResult res;
  res.block_index = head.u64();
  const uint64_t fc = head.u64();
  if (fc > UINT32_MAX) throw WireError("first_channel out of range");
  res.first_channel = static_cast<uint32_t>(fc);
  res.tallies.resize(head.count(1));
  const size_t at = head.pos();
  const size_t body_at = at + get_tallies(bytes.substr(at), res.tallies);
  Reader r(bytes.substr(body_at));
  const uint64_t nc = r.count(8);
  if (nc > Counters::kMaxCounters) throw WireError(fmt::format("{} counters (at most {})", nc, Counters::kMaxCounters));
  res.counters.values.resize(nc);
  for (auto& v : res.counters.values) v = r.u64();
  res.tail = r.tail();
  res.weights = r.weights();
  if (r.u8() != 0) res.fault = r.fault();
  res.aux.resize(r.count(8));
  for (double& v : res.aux) v = r.f64();
  const uint64_t fs = r.u64();
  if (fs > UINT32_MAX) throw WireError("first_sum out of range");
  res.first_sum = static_cast<uint32_t>(fs);
  res.sums.resize(r.count(1));  // at least a tag byte each
  const size_t at_sums = body_at + r.pos();
  if (bytes.size() - at_sums != get_sums(bytes.substr(at_sums), res.sums)) {
    throw WireError("trailing bytes after a result");
  }
  return res;
}

void append_entry_result(std::string& entry, std::string_view encoded_result) {
  if (encoded_result.size() > UINT32_MAX) throw WireError("a block result over 4 GiB cannot travel");
  const auto n = static_cast<uint32_t>(encoded_result.size());
  for (int i = 0; i < 4; ++i) entry.push_back(static_cast<char>((n >> (8 * i)) & 0xff));
  entry.append(encoded_result);
}

std::vector<BlockResult> decode_entry_results(std::string_view bytes) {
  if (bytes.empty()) throw WireError("an entry's results are empty");
  std::vector<BlockResult> out;
  size_t at = 0;
  while (at < bytes.size()) {
    if (bytes.size() - at < 4) throw WireError(fmt::format("entry results are truncated at byte {}", at));
    uint32_t n = 0;
    for (int i = 0; i < 4; ++i) n |= static_cast<uint32_t>(static_cast<unsigned char>(bytes[at + static_cast<size_t>(i)])) << (8 * i);
    at += 4;
    if (bytes.size() - at < n) throw WireError(fmt::format("entry results are truncated at byte {} (a result of {} bytes)", at, n));
    out.push_back(decode_result(bytes.substr(at, n)));
    at += n;
  }
  return out;
}

}  // namespace tally::cluster

namespace tally::cluster {

std::string result_digest(std::string_view encoded) {
  return sha1_hex(encoded);
}

}  // namespace tally::cluster
