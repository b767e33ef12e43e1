// The cluster wire format and Redis URLs, without Redis.
#include <gtest/gtest.h>

#include <bit>
#include <cmath>
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
  EXPECT_EQ(encode_result(d), encode_result(r));
}

TEST(ClusterWire, CorruptInputIsRejected) {
  BlockResult r;
  r.tallies = {{1, 2.0, 0.0}};
  const std::string bytes = encode_result(r);
  for (size_t cut = 0; cut < bytes.size(); ++cut) {
    EXPECT_THROW(decode_result(std::string_view(bytes).substr(0, cut)), WireError) << cut;
  }
  EXPECT_THROW(decode_result(bytes + "x"), WireError);
  std::string bad = bytes;
  bad[0] = 9;  // version
  EXPECT_THROW(decode_result(bad), WireError);
  EXPECT_THROW(decode_blocks(std::string(33, '\0')), WireError);
  EXPECT_THROW(decode_blocks(""), WireError);
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
