#include "common/engine/checkpoint.hpp"

#include <gtest/gtest.h>

#include <bit>
#include <cmath>

namespace tally {
namespace {

JobState sample_state() {
  JobState s;
  s.passes = 3;
  s.samples = 12345;
  s.partition_samples = {12345, 77};
  s.channels.resize(3);
  s.channels[0].n = 12345;
  s.channels[0].mean = 0.1 + 0.2;  // a value with a long binary expansion
  s.channels[0].m2 = 1.0 / 3.0;
  s.channels[2].n = 1;
  s.channels[2].mean = -0.0;
  s.counters.add(Counter::evaluations, 999);
  s.counters.add(Counter::shadow_rays, 5);
  s.tail.offer(3.5);
  s.tail.offer(1e300);
  s.weights.add(0.25);
  SampleFault f;
  f.sample_index = 42;
  f.value = std::nan("");
  f.point = {0.5, 1e-300};
  f.message = "the integrand is NaN at x0 = 0.5";
  s.fault = f;
  s.compute_seconds = 1.25;
  s.trace = {{0.1, 100, 0.3, 0.01}, {0.2, 200, 0.31, 0.007}};
  s.kernel_state = std::string("VEGAS grid\0bytes", 16);
  return s;
}

TEST(Checkpoint, RoundTripIsBitExact) {
  const JobState s = sample_state();
  const JobState r = decode_checkpoint(encode_checkpoint(s));
  EXPECT_EQ(r.passes, s.passes);
  EXPECT_EQ(r.samples, s.samples);
  EXPECT_EQ(r.partition_samples, s.partition_samples);
  ASSERT_EQ(r.channels.size(), s.channels.size());
  for (size_t i = 0; i < s.channels.size(); ++i) {
    EXPECT_EQ(r.channels[i].n, s.channels[i].n);
    EXPECT_EQ(std::bit_cast<uint64_t>(r.channels[i].mean), std::bit_cast<uint64_t>(s.channels[i].mean));
    EXPECT_EQ(std::bit_cast<uint64_t>(r.channels[i].m2), std::bit_cast<uint64_t>(s.channels[i].m2));
  }
  EXPECT_EQ(r.counters, s.counters);
  EXPECT_EQ(r.tail.sorted_values(), s.tail.sorted_values());
  EXPECT_EQ(r.weights, s.weights);
  ASSERT_TRUE(r.fault.has_value());
  EXPECT_EQ(r.fault->message, s.fault->message);
  EXPECT_EQ(r.fault->point, s.fault->point);
  EXPECT_TRUE(std::isnan(r.fault->value));
  EXPECT_EQ(r.compute_seconds, s.compute_seconds);
  EXPECT_EQ(r.trace, s.trace);
  EXPECT_EQ(r.kernel_state, s.kernel_state);
}

// Version 1 (before JobState::kernel_state) still reads, with no kernel state: the
// v1 bytes are the v2 bytes without the trailing kernel_state field.
TEST(Checkpoint, VersionOneStillReads) {
  JobState s = sample_state();
  s.kernel_state.clear();
  std::string v2 = encode_checkpoint(s);
  std::string body = v2.substr(0, v2.size() - 16);  // drop the empty bytes field (its length) and the checksum
  ASSERT_EQ(body[8], 2);
  body[8] = 1;
  uint64_t h = 0xcbf29ce484222325ULL;  // FNV-1a, as the format's checksum
  for (unsigned char c : body) {
    h ^= c;
    h *= 0x100000001b3ULL;
  }
  for (int i = 0; i < 8; ++i) body.push_back(static_cast<char>((h >> (8 * i)) & 0xff));
  const JobState r = decode_checkpoint(body);
  EXPECT_EQ(r.samples, s.samples);
  EXPECT_EQ(r.trace, s.trace);
  EXPECT_TRUE(r.kernel_state.empty());
  body[8] = 3;
  EXPECT_THROW(decode_checkpoint(body), CheckpointError);  // unknown version (and checksum)
}

TEST(Checkpoint, EveryTruncationIsReported) {
  const std::string bytes = encode_checkpoint(sample_state());
  for (size_t len = 0; len < bytes.size(); ++len) {
    EXPECT_THROW(decode_checkpoint(std::string_view(bytes).substr(0, len)), CheckpointError) << len;
  }
}

TEST(Checkpoint, EverySingleByteCorruptionIsReported) {
  const std::string bytes = encode_checkpoint(sample_state());
  for (size_t i = 0; i < bytes.size(); ++i) {
    std::string bad = bytes;
    bad[i] = static_cast<char>(bad[i] ^ 0x5a);
    EXPECT_THROW(decode_checkpoint(bad), CheckpointError) << i;
  }
}

TEST(Checkpoint, GarbageIsReported) {
  EXPECT_THROW(decode_checkpoint("hello"), CheckpointError);
  EXPECT_THROW(decode_checkpoint(std::string(1000, '\0')), CheckpointError);
}

}  // namespace
}  // namespace tally
