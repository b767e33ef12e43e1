#include "common/engine/checkpoint.hpp"

#include <gtest/gtest.h>

#include <bit>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <sstream>
#include <string_view>
#include <vector>

#include "common/engine/job_runner.hpp"

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
  s.sums = {0.1f + 0.2f, -0.0f, 1e-40f, -7.5f};  // sum channels (an image's replicates; 1e-40f is subnormal)
  s.counter_names = {"evaluations", "shadow_rays"};  // a kernel's own counters
  s.counters.add(0, 999);
  s.counters.add(1, 5);
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
  ASSERT_EQ(r.sums.size(), s.sums.size());
  for (size_t i = 0; i < s.sums.size(); ++i) {
    EXPECT_EQ(std::bit_cast<uint32_t>(r.sums[i]), std::bit_cast<uint32_t>(s.sums[i])) << i;
  }
  EXPECT_EQ(r.counters, s.counters);
  EXPECT_EQ(r.counter_names, s.counter_names);
  EXPECT_EQ(r.tail.sorted_values(), s.tail.sorted_values());
  EXPECT_EQ(r.weights, s.weights);
  ASSERT_TRUE(r.fault.has_value());
  EXPECT_EQ(r.fault->message, s.fault->message);
  EXPECT_EQ(r.fault->point, s.fault->point);
  EXPECT_TRUE(std::isnan(r.fault->value));
  EXPECT_EQ(r.compute_seconds, s.compute_seconds);
  EXPECT_EQ(r.trace, s.trace);
  EXPECT_EQ(r.kernel_state, s.kernel_state);
  EXPECT_EQ(r.results_version, kResultsVersion);
  // A state carries the version that computed it, not the reader's.
  JobState older = s;
  older.results_version = kResultsVersion + 7;
  EXPECT_EQ(decode_checkpoint(encode_checkpoint(older)).results_version, kResultsVersion + 7);
}

std::string read_v2_fixture() {
  // Written by the version-2 encoder (main at 0e6e30c, before kernels declared their
  // own counters): passes 3, samples 12345, partitions {12345, 77}, channels as in
  // sample_state(), counters evaluations 999, nonfinite 2, shadow_rays 5,
  // roulette_terminations 7 in the fixed 14-slot list, no fault, the same trace and
  // kernel_state.
  std::ifstream in(TALLY_SOURCE_DIR "/tests/engine/data/checkpoint_v2.bin", std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

std::string with_checksum(std::string body) {
  uint64_t h = 0xcbf29ce484222325ULL;  // FNV-1a, as the format's checksum
  for (unsigned char c : body) {
    h ^= c;
    h *= 0x100000001b3ULL;
  }
  for (int i = 0; i < 8; ++i) body.push_back(static_cast<char>((h >> (8 * i)) & 0xff));
  return body;
}

uint64_t named(const JobState& s, const std::string& name) {
  for (size_t i = 0; i < s.counter_names.size(); ++i) {
    if (s.counter_names[i] == name) return s.counters[i];
  }
  return UINT64_MAX;
}

// Version 2 (a fixed list of 14 counters) still reads: every counter under the name
// it had in that list.
// The fuzz target's seeds (tests/fuzz/corpus/checkpoint) all decode, and one is of the
// current version, sum channels included, and re-encodes to exactly its own bytes.
TEST(Checkpoint, FuzzSeedsDecodeAndOneIsCurrent) {
  const std::filesystem::path dir = std::filesystem::path(TALLY_SOURCE_DIR) / "tests/fuzz/corpus/checkpoint";
  size_t current = 0;
  for (const auto& e : std::filesystem::directory_iterator(dir)) {
    std::ifstream in(e.path(), std::ios::binary);
    const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    try {
      const JobState s = decode_checkpoint(bytes);
      if (encode_checkpoint(s) == bytes) {
        ++current;
        EXPECT_EQ(s.sums.size(), 4u) << e.path();
        EXPECT_EQ(std::bit_cast<uint32_t>(s.sums[1]), std::bit_cast<uint32_t>(-0.0f));
      }
    } catch (const CheckpointError& err) {
      ADD_FAILURE() << e.path() << ": " << err.what();
    }
  }
  EXPECT_EQ(current, 1u);
}

TEST(Checkpoint, VersionTwoStillReads) {
  const std::string v2 = read_v2_fixture();
  ASSERT_EQ(v2.size(), 424u);
  ASSERT_EQ(v2[8], 2);
  const JobState r = decode_checkpoint(v2);
  const JobState s = sample_state();
  EXPECT_EQ(r.passes, 3u);
  EXPECT_EQ(r.samples, 12345u);
  EXPECT_EQ(r.partition_samples, (std::vector<uint64_t>{12345, 77}));
  ASSERT_EQ(r.channels.size(), 3u);
  EXPECT_EQ(std::bit_cast<uint64_t>(r.channels[0].mean), std::bit_cast<uint64_t>(0.1 + 0.2));
  EXPECT_EQ(std::bit_cast<uint64_t>(r.channels[0].m2), std::bit_cast<uint64_t>(1.0 / 3.0));
  EXPECT_TRUE(std::signbit(r.channels[2].mean));
  ASSERT_EQ(r.counter_names.size(), 14u);
  EXPECT_EQ(r.counter_names[0], "evaluations");
  EXPECT_EQ(r.counter_names[13], "roulette_terminations");
  EXPECT_EQ(named(r, "evaluations"), 999u);
  EXPECT_EQ(named(r, "nonfinite"), 2u);
  EXPECT_EQ(named(r, "shadow_rays"), 5u);
  EXPECT_EQ(named(r, "roulette_terminations"), 7u);
  EXPECT_EQ(named(r, "rejection_attempts"), 0u);
  EXPECT_EQ(r.tail.sorted_values(), s.tail.sorted_values());
  EXPECT_EQ(r.weights, s.weights);
  EXPECT_FALSE(r.fault.has_value());
  EXPECT_EQ(r.compute_seconds, 1.25);
  EXPECT_EQ(r.trace, s.trace);
  EXPECT_EQ(r.kernel_state, s.kernel_state);
  // Written before results were versioned: its version is unknown (0), so the result
  // cache never answers a submit from it.
  EXPECT_EQ(r.results_version, 0u);
  EXPECT_TRUE(r.sums.empty());  // before version 5: no sum channels
  // Re-encoded, it is a version-6 checkpoint that reads back the same, version 0 kept.
  const std::string v6 = encode_checkpoint(r);
  EXPECT_EQ(v6[8], 6);
  const JobState again = decode_checkpoint(v6);
  EXPECT_EQ(again.counter_names, r.counter_names);
  EXPECT_EQ(again.counters, r.counters);
  EXPECT_EQ(again.results_version, 0u);
}

// Version 5 stored the sums as doubles; they read rounded to the float this build keeps
// (a subnormal double below the float range reads as 0), the rest of the state as written.
TEST(Checkpoint, VersionFiveSumsReadRoundedToFloat) {
  const std::filesystem::path p = std::filesystem::path(TALLY_SOURCE_DIR) / "tests/fuzz/corpus/checkpoint/state4_v5_sums";
  std::ifstream in(p, std::ios::binary);
  const std::string v5((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  ASSERT_EQ(v5[8], 5);
  const JobState s = decode_checkpoint(v5);
  ASSERT_EQ(s.sums.size(), 4u);
  EXPECT_EQ(s.sums[0], 0.5f);
  EXPECT_EQ(std::bit_cast<uint32_t>(s.sums[1]), std::bit_cast<uint32_t>(-0.0f));
  EXPECT_EQ(std::bit_cast<uint32_t>(s.sums[2]), 0u);  // 1e-310
  EXPECT_EQ(s.sums[3], 7.25f);
  EXPECT_EQ(s.partition_samples.size(), 2u);
  const std::string v6 = encode_checkpoint(s);
  EXPECT_EQ(v6[8], 6);
  EXPECT_EQ(v6.size(), v5.size() - 4 * 4) << "4 bytes a sum, not 8";
}

// Version 1 (before JobState::kernel_state) still reads, with no kernel state: the
// v1 bytes are the v2 bytes without the trailing kernel_state field.
TEST(Checkpoint, VersionOneStillReads) {
  const std::string v2 = read_v2_fixture();
  std::string body = v2.substr(0, v2.size() - 8 - 8 - 16);  // drop kernel_state (length, 16 bytes) and checksum
  ASSERT_EQ(body[8], 2);
  body[8] = 1;
  const JobState r = decode_checkpoint(with_checksum(body));
  EXPECT_EQ(r.samples, 12345u);
  EXPECT_EQ(r.trace, sample_state().trace);
  EXPECT_EQ(named(r, "shadow_rays"), 5u);
  EXPECT_TRUE(r.kernel_state.empty());
  EXPECT_EQ(r.results_version, 0u);
  body[8] = 6;
  EXPECT_THROW(decode_checkpoint(with_checksum(body)), CheckpointError);  // unknown version
}

// A kernel with three channels and two partitions, like the fixture's job, counting
// what it declares.
class NamedCountersKernel final : public Kernel {
 public:
  explicit NamedCountersKernel(std::vector<std::string_view> names) : names_(std::move(names)) {}
  size_t channel_count() const override { return 3; }
  uint32_t partition_count() const override { return 2; }
  std::span<const std::string_view> counter_names() const override { return names_; }
  void run_block(const Block&, BlockResult&) const override {}

 private:
  std::vector<std::string_view> names_;
};

// A resumed job maps the checkpoint's counters onto its kernel's by name, whatever
// their order; a non-zero counter the kernel does not declare is another job's.
TEST(Checkpoint, ResumedCountersMapByName) {
  const JobState v2 = decode_checkpoint(read_v2_fixture());
  StopRule rule;
  rule.max_samples = 1u << 20;
  auto k = std::make_shared<NamedCountersKernel>(
      std::vector<std::string_view>{"shadow_rays", "roulette_terminations", "nonfinite", "evaluations", "camera_rays"});
  const JobRunner resumed(k, rule, JobCaps{}, v2);
  const JobState& st = resumed.state();
  EXPECT_EQ(st.counter_names,
            (std::vector<std::string>{"shadow_rays", "roulette_terminations", "nonfinite", "evaluations", "camera_rays"}));
  EXPECT_EQ(st.counters.values, (std::vector<uint64_t>{5, 7, 2, 999, 0}));
  // The same kernel resuming its own (version 3) checkpoint keeps everything.
  const JobRunner again(k, rule, JobCaps{}, decode_checkpoint(encode_checkpoint(st)));
  EXPECT_EQ(again.state().counters.values, st.counters.values);

  auto other = std::make_shared<NamedCountersKernel>(std::vector<std::string_view>{"evaluations", "nonfinite"});
  EXPECT_THROW(JobRunner(other, rule, JobCaps{}, v2), std::invalid_argument);  // shadow_rays 5 has no home
}

// A checkpoint whose body is `body`, with the checksum recomputed: damage sealed this way
// passes the checksum and reaches the parser's own checks (issue 27: the checksum alone
// rejected every damaged input before the parser ran).
std::string sealed(std::string body) {
  const uint64_t h = checkpoint_checksum(body);
  for (int i = 0; i < 8; ++i) body.push_back(static_cast<char>((h >> (8 * i)) & 0xff));
  return body;
}

TEST(Checkpoint, EveryTruncationIsReported) {
  const std::string bytes = encode_checkpoint(sample_state());
  for (size_t len = 0; len < bytes.size(); ++len) {  // the checksum's part
    EXPECT_THROW(decode_checkpoint(std::string_view(bytes).substr(0, len)), CheckpointError) << len;
  }
  const std::string body = bytes.substr(0, bytes.size() - 8);
  ASSERT_EQ(sealed(body), bytes);  // sealing is what encode_checkpoint does
  // The parser's part: every proper prefix of the body, behind a valid checksum.
  for (size_t len = 0; len < body.size(); ++len) {
    EXPECT_THROW(decode_checkpoint(sealed(body.substr(0, len))), CheckpointError) << len;
  }
  // Bytes after the last field are reported too, never ignored.
  EXPECT_THROW(decode_checkpoint(sealed(body + std::string(1, '\0'))), CheckpointError);
  EXPECT_THROW(decode_checkpoint(sealed(body + bytes)), CheckpointError);
}

TEST(Checkpoint, EverySingleByteCorruptionIsReported) {
  const std::string bytes = encode_checkpoint(sample_state());
  for (size_t i = 0; i < bytes.size(); ++i) {  // the checksum's part
    std::string bad = bytes;
    bad[i] = static_cast<char>(bad[i] ^ 0x5a);
    EXPECT_THROW(decode_checkpoint(bad), CheckpointError) << i;
  }
  // The parser's part, behind a valid checksum: a damaged byte is either reported or
  // read as exactly what it says (the decoded state encodes back to the same bytes:
  // nothing skipped, nothing reinterpreted). Structural bytes (version, counts, lengths,
  // flags) must be reported: count them.
  const std::string body = bytes.substr(0, bytes.size() - 8);
  size_t reported = 0, read_back = 0;
  for (size_t i = 0; i < body.size(); ++i) {
    for (unsigned char flip : {0x01, 0x5a, 0x80}) {
      std::string bad = body;
      bad[i] = static_cast<char>(bad[i] ^ flip);
      const std::string input = sealed(bad);
      try {
        const JobState s = decode_checkpoint(input);
        EXPECT_EQ(encode_checkpoint(s), input) << "byte " << i << " ^ " << int{flip} << " was misread";
        ++read_back;
      } catch (const CheckpointError&) {
        ++reported;
      }
    }
  }
  std::printf("single-byte damage behind a valid checksum: %zu reported, %zu read back exactly\n", reported,
              read_back);
  // The magic (8 bytes) and the version's low byte are always reported; each count or
  // length field's low byte too (a count changed by 1 leaves bytes over or missing).
  EXPECT_GE(reported, 3u * 9u);
  EXPECT_GT(read_back, 0u);  // value bytes are read, not rejected wholesale
}

TEST(Checkpoint, GarbageIsReported) {
  EXPECT_THROW(decode_checkpoint("hello"), CheckpointError);
  EXPECT_THROW(decode_checkpoint(std::string(1000, '\0')), CheckpointError);
}

// write_checkpoint hands a store the checkpoint in pieces of the size asked for (so no
// buffer of the whole checkpoint and no blob over SQLite's limit): every piece but the
// last has exactly that size, the last is not empty, and joined they are
// encode_checkpoint's bytes, which decode to the same state.
TEST(Checkpoint, StreamedInPiecesOfTheGivenSize) {
  JobState s = sample_state();
  s.channels.resize(1000);  // 24,000 bytes of tallies
  for (size_t i = 0; i < s.channels.size(); ++i) s.channels[i].add(static_cast<double>(i) * 0.37);
  const std::string whole = encode_checkpoint(s);
  ASSERT_GT(whole.size(), 24000u);
  for (const size_t piece : {size_t{1}, size_t{7}, size_t{100}, size_t{4096}, whole.size(), whole.size() + 1}) {
    std::vector<std::string> pieces;
    const uint64_t total = write_checkpoint(s, [&](std::string_view p) { pieces.emplace_back(p); }, piece);
    EXPECT_EQ(total, whole.size()) << piece;
    ASSERT_EQ(pieces.size(), (whole.size() + piece - 1) / piece) << piece;
    std::string joined;
    for (size_t i = 0; i < pieces.size(); ++i) {
      if (i + 1 < pieces.size()) {
        EXPECT_EQ(pieces[i].size(), piece) << "piece " << i << " of " << piece;
      }
      EXPECT_FALSE(pieces[i].empty());
      joined += pieces[i];
    }
    EXPECT_EQ(joined, whole) << piece;
  }
  EXPECT_EQ(encode_checkpoint(decode_checkpoint(whole)), whole);
}

}  // namespace
}  // namespace tally
