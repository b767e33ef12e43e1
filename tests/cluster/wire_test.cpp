// The cluster wire format and Redis URLs, without Redis.
#include <gtest/gtest.h>

#include <bit>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>

#include "server/cluster/assets.hpp"
#include "server/cluster/redis_conn.hpp"
#include "server/cluster/wire.hpp"

namespace tally::cluster {
namespace {

TEST(ClusterWire, ResultRoundTripIsBitExact) {
  BlockResult r;
  r.block_index = 77;
  r.first_channel = 3;
  r.tallies = {{10, 0.1 + 0.2, 1e-300}, {0, -0.0, 0.0}, {5, std::nextafter(1.0, 2.0), 3.5}};
  r.counters.add(0, 123);  // the kernel's counter ids
  r.counters.add(3, 9);
  for (double v : {3.0, 1.0, 7.0, 2.0, 9.0, 0.5}) r.tail.offer(v);
  r.weights.add(0.25);
  r.weights.add(4.0);
  r.aux = {1.5, -0.0, 1e-310};
  r.first_sum = 96;
  r.sums = {0.1 + 0.2, -0.0, 1e-310, 0.0, 0.0, 1e-310, 1e-310};  // -0.0 is a literal, +0.0 a tag
  r.fault = SampleFault{42, 1, std::numeric_limits<double>::infinity(), {0.5, -0.25}, "x0 = 0.5: inf"};
  const BlockResult d = decode_result(encode_result(r));
  EXPECT_EQ(d.block_index, 77u);
  EXPECT_EQ(d.first_channel, 3u);
  ASSERT_EQ(d.tallies.size(), 3u);
  for (size_t i = 0; i < 3; ++i) {
    EXPECT_EQ(d.tallies[i].n, r.tallies[i].n);
    EXPECT_EQ(std::bit_cast<uint64_t>(d.tallies[i].mean), std::bit_cast<uint64_t>(r.tallies[i].mean));
    EXPECT_EQ(std::bit_cast<uint64_t>(d.tallies[i].m2), std::bit_cast<uint64_t>(r.tallies[i].m2));
  }
  EXPECT_EQ(d.counters, r.counters);
  EXPECT_EQ(d.tail.heap(), r.tail.heap());  // same layout: merges stay bit-identical
  EXPECT_EQ(d.tail.capacity(), r.tail.capacity());
  EXPECT_EQ(d.weights, r.weights);
  ASSERT_TRUE(d.fault);
  EXPECT_EQ(d.fault->message, "x0 = 0.5: inf");
  EXPECT_EQ(d.fault->point, r.fault->point);
  ASSERT_EQ(d.aux.size(), 3u);
  for (size_t i = 0; i < 3; ++i) EXPECT_EQ(std::bit_cast<uint64_t>(d.aux[i]), std::bit_cast<uint64_t>(r.aux[i]));
  EXPECT_EQ(d.first_sum, 96u);
  ASSERT_EQ(d.sums.size(), r.sums.size());
  for (size_t i = 0; i < r.sums.size(); ++i) {
    EXPECT_EQ(std::bit_cast<uint64_t>(d.sums[i]), std::bit_cast<uint64_t>(r.sums[i])) << i;
  }
  EXPECT_EQ(encode_result(d), encode_result(r));
}

TEST(ClusterWire, CompactTalliesAreBitExactAndSmall) {
  // Counts across the head byte's limit (63) and up to 2^64 - 1, zero and non-zero
  // doubles of every kind: each decodes to the same bits.
  BlockResult r;
  const double nan = std::bit_cast<double>(0x7ff8000000000123ULL);
  for (uint64_t n : std::initializer_list<uint64_t>{0, 1, 2, 62, 63, 64, 63 + 127, 63 + 128, 1ULL << 40, UINT64_MAX - 1, UINT64_MAX}) {
    for (double mean : {0.0, -0.0, 1.0 / 3.0, nan, 1e-310}) {
      for (double m2 : {0.0, -0.0, 2.5, std::numeric_limits<double>::infinity()}) r.tallies.push_back({n, mean, m2});
    }
  }
  const BlockResult d = decode_result(encode_result(r));
  ASSERT_EQ(d.tallies.size(), r.tallies.size());
  for (size_t i = 0; i < r.tallies.size(); ++i) {
    EXPECT_EQ(d.tallies[i].n, r.tallies[i].n) << i;
    EXPECT_EQ(std::bit_cast<uint64_t>(d.tallies[i].mean), std::bit_cast<uint64_t>(r.tallies[i].mean)) << i;
    EXPECT_EQ(std::bit_cast<uint64_t>(d.tallies[i].m2), std::bit_cast<uint64_t>(r.tallies[i].m2)) << i;
  }
  // A pixel channel seen once in a block (n 1, M2 exactly +0) costs 9 bytes instead of
  // 24, an unseen one 1 byte, one seen twice 17; a tally equal to the one before it (a
  // grey pixel's G and B, a black pixel) 1 byte.
  BlockResult image;
  for (int i = 0; i < 1000; ++i) image.tallies.push_back({1, 0.25 + i, 0.0});
  const size_t base = encode_result(BlockResult{}).size();
  EXPECT_EQ(encode_result(image).size(), base + 1000 * 9);
  image.tallies.assign(1000, Tally{});
  EXPECT_EQ(encode_result(image).size(), base + 1000);
  image.tallies.clear();
  for (int i = 0; i < 1000; ++i) image.tallies.push_back({2, 0.25 + i, 0.5});
  EXPECT_EQ(encode_result(image).size(), base + 1000 * 17);
  image.tallies.clear();
  for (int i = 0; i < 1000; ++i) image.tallies.insert(image.tallies.end(), 3, Tally{2, 0.25 + i, 0.5});
  EXPECT_EQ(encode_result(image).size(), base + 1000 * (17 + 1 + 1));
  // Equal in value is not enough: -0.0 differs from +0.0, and a NaN's payload counts.
  image.tallies = {{1, 0.0, 0.0}, {1, -0.0, 0.0}, {1, nan, 0.0}, {1, std::bit_cast<double>(0x7ff8000000000124ULL), 0.0},
                   {1, std::bit_cast<double>(0x7ff8000000000124ULL), 0.0}};
  const BlockResult g = decode_result(encode_result(image));
  ASSERT_EQ(g.tallies.size(), 5u);
  for (size_t i = 0; i < 5; ++i) {
    EXPECT_EQ(std::bit_cast<uint64_t>(g.tallies[i].mean), std::bit_cast<uint64_t>(image.tallies[i].mean)) << i;
  }
  EXPECT_EQ(encode_result(image).size(), base + 1 + 9 + 9 + 9 + 1);
}

// The fuzz target's seeds (tests/fuzz/corpus/cluster_wire) are of this build's format:
// seeds a version bump left behind would stop at the version byte and fuzz nothing. (A
// seed may be refused further in, e.g. one_result: its tail is not a heap.)
TEST(ClusterWire, FuzzSeedsDecodeUnderThisVersion) {
  const std::filesystem::path dir = std::filesystem::path(TALLY_SOURCE_DIR) / "tests/fuzz/corpus/cluster_wire";
  size_t results = 0, sums = 0;
  for (const auto& e : std::filesystem::directory_iterator(dir)) {
    std::ifstream in(e.path(), std::ios::binary);
    const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    if (e.path().filename() == "blocks") {
      EXPECT_NO_THROW(decode_blocks(bytes));
      continue;
    }
    try {
      for (const BlockResult& r : decode_entry_results(bytes)) {
        ++results;
        sums += r.sums.size();
      }
    } catch (const WireError& err) {
      EXPECT_EQ(std::string(err.what()).find("version"), std::string::npos) << e.path() << ": " << err.what();
    }
  }
  EXPECT_GE(results, 4u);
  EXPECT_GT(sums, 0u);  // one seed carries sum channels
}

TEST(ClusterWire, ResultDigestIsTheSha1Hex) {
  EXPECT_EQ(result_digest("abc"), "a9993e364706816aba3e25717850c26c9cd0d89d");  // FIPS 180 test vector
  EXPECT_EQ(result_digest(""), "da39a3ee5e6b4b0d3255bfef95601890afd80709");
}

TEST(ClusterWire, CorruptInputIsRejected) {
  BlockResult r;
  r.tallies = {{1, 2.0, 0.0}};
  const std::string bytes = encode_result(r);
  for (size_t cut = 0; cut < bytes.size(); ++cut) {
    EXPECT_THROW(decode_result(std::string_view(bytes).substr(0, cut)), WireError) << cut;
  }
  EXPECT_THROW(decode_result(bytes + "x"), WireError);
  // Sums: every cut is refused, a repeat first, an undefined tag, a first_sum beyond 32 bits.
  BlockResult s;
  s.sums = {1.0, 1.0, 0.0};  // literal, repeat, zero: 9 + 1 + 1 bytes
  std::string sums = encode_result(s);
  EXPECT_EQ(static_cast<unsigned char>(sums[sums.size() - 2]), 1u);  // the repeat tag
  for (size_t cut = 1; cut <= 11; ++cut) EXPECT_THROW(decode_result(sums.substr(0, sums.size() - cut)), WireError) << cut;
  std::string bad_sums = sums;
  bad_sums[sums.size() - 11] = 1;  // the first sum's tag: a repeat of nothing
  EXPECT_THROW(decode_result(bad_sums), WireError);
  bad_sums[sums.size() - 11] = 3;  // not a tag
  EXPECT_THROW(decode_result(bad_sums), WireError);
  sums[sums.size() - 11 - 8 - 4] = 1;  // first_sum's fifth byte: 2^32
  EXPECT_THROW(decode_result(sums), WireError);
  // A count that overflows 64 bits in the varint, or in 63 + varint.
  BlockResult big;
  big.tallies = {{UINT64_MAX, 0.0, 0.0}};
  std::string over = encode_result(big);
  const size_t head = over.size() - 8 /*counters*/ - 16 /*tail*/ - 16 /*weights*/ - 1 /*fault*/ - 8 /*aux*/ - 16 /*first_sum, sums*/ - 11;
  ASSERT_EQ(static_cast<unsigned char>(over[head]), 62u << 2);
  over[head + 10] = 2;  // the varint's last byte: bit 64 set
  EXPECT_THROW(decode_result(over), WireError);
  std::string bad = bytes;
  bad[0] = 9;  // version
  EXPECT_THROW(decode_result(bad), WireError);
  // The repeat code (head 0xfc) with nothing before it, and the head bytes 0xfd-0xff.
  BlockResult two;
  two.tallies = {{1, 2.0, 0.0}, {1, 2.0, 0.0}};
  const std::string rep = encode_result(two);
  const size_t at = rep.size() - 8 - 16 - 16 - 1 - 8 - 16 - 10;  // first head, 8 bytes of mean, repeat
  ASSERT_EQ(static_cast<unsigned char>(rep[at + 9]), 0xfcu);
  EXPECT_EQ(decode_result(rep).tallies.at(1).mean, 2.0);
  std::string first_repeats = rep;
  first_repeats.erase(at, 9);  // the literal goes: the repeat comes first
  first_repeats[17] = 1;       // one tally
  EXPECT_THROW(decode_result(first_repeats), WireError);
  for (unsigned h : {0xfdu, 0xfeu, 0xffu}) {
    std::string undefined = rep;
    undefined[at + 9] = static_cast<char>(h);
    EXPECT_THROW(decode_result(undefined), WireError) << h;
  }
  EXPECT_THROW(decode_blocks(std::string(33, '\0')), WireError);
  EXPECT_THROW(decode_blocks(""), WireError);
}

TEST(ClusterWire, EntryResultsRoundTripInOrderAndRejectDamage) {
  // An entry's results are one Redis field: each block's result behind its length.
  std::vector<BlockResult> in(3);
  for (size_t i = 0; i < in.size(); ++i) {
    in[i].block_index = 40 + i;
    in[i].tallies = {{i + 1, 0.1 * static_cast<double>(i), 0.0}};
  }
  std::string entry;
  for (const BlockResult& r : in) append_entry_result(entry, encode_result(r));
  const std::vector<BlockResult> out = decode_entry_results(entry);
  ASSERT_EQ(out.size(), 3u);
  for (size_t i = 0; i < 3; ++i) EXPECT_EQ(encode_result(out[i]), encode_result(in[i])) << i;
  EXPECT_THROW(decode_entry_results(""), WireError);                                  // no result at all
  EXPECT_THROW(decode_entry_results(entry.substr(0, entry.size() - 1)), WireError);   // cut in a result
  EXPECT_THROW(decode_entry_results(entry.substr(0, 2)), WireError);                  // cut in a length
  EXPECT_THROW(decode_entry_results(entry + std::string(4, '\0')), WireError);       // an empty result
  std::string longer = entry;
  longer[0] = static_cast<char>(static_cast<unsigned char>(longer[0]) + 1);           // a length past its result
  EXPECT_THROW(decode_entry_results(longer), WireError);
}

TEST(ClusterWire, BlocksRoundTrip) {
  const Block a{5, 1ULL << 40, 4096, 17}, b{6, 12, 1, 0};
  const auto v = decode_blocks(encode_block(a) + encode_block(b));
  ASSERT_EQ(v.size(), 2u);
  EXPECT_EQ(v[0].index, 5u);
  EXPECT_EQ(v[0].first_sample, 1ULL << 40);
  EXPECT_EQ(v[0].sample_count, 4096u);
  EXPECT_EQ(v[0].partition, 17u);
  EXPECT_EQ(v[1].index, 6u);
}

TEST(ClusterUrl, ParsesTheDocumentedForms) {
  RedisUrl u = parse_redis_url("redis://:s3cret@10.0.0.5:6380/2");
  EXPECT_EQ(u.host, "10.0.0.5");
  EXPECT_EQ(u.port, 6380);
  EXPECT_EQ(u.password, "s3cret");
  EXPECT_EQ(u.user, "");
  EXPECT_EQ(u.db, 2);
  EXPECT_EQ(u.display().find("s3cret"), std::string::npos);
  u = parse_redis_url("redis://tally:pw@redis");
  EXPECT_EQ(u.user, "tally");
  EXPECT_EQ(u.password, "pw");
  EXPECT_EQ(u.port, 6379);
  u = parse_redis_url("unix:///run/redis/r.sock");
  EXPECT_EQ(u.unix_path, "/run/redis/r.sock");
  EXPECT_TRUE(u.password.empty());
  u = parse_redis_url("unix://tally:p@ss@/run/redis/r.sock?db=3");
  EXPECT_EQ(u.unix_path, "/run/redis/r.sock");
  EXPECT_EQ(u.user, "tally");
  EXPECT_EQ(u.password, "p@ss");
  EXPECT_EQ(u.db, 3);
  EXPECT_EQ(u.display(), "unix://tally@/run/redis/r.sock");
  u = parse_redis_url("unix://secret@/r.sock");
  EXPECT_EQ(u.password, "secret");
  EXPECT_TRUE(u.user.empty());
  EXPECT_THROW(parse_redis_url("rediss://host"), std::invalid_argument);
  EXPECT_THROW(parse_redis_url("redis://host:99999"), std::invalid_argument);
  EXPECT_THROW(parse_redis_url("redis://host:x"), std::invalid_argument);
  EXPECT_THROW(parse_redis_url("unix://relative.sock"), std::invalid_argument);
  EXPECT_THROW(parse_redis_url("redis://"), std::invalid_argument);
}

TEST(ClusterAssets, Sha256MatchesTheStandardVector) {
  EXPECT_EQ(sha256_hex("abc"), "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
}

}  // namespace
}  // namespace tally::cluster
