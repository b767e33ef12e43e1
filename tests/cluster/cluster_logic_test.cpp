// The cluster's pure parts, without Redis: the key grammar (redis_layout.hpp), pool
// names, how a pass is cut into entries and its results checked (pass_entries), and
// what the coordinator concludes from a pass's state (pass_verdict).
#include <gtest/gtest.h>

#include "common/spec/pool_field.hpp"
#include "server/cluster/pass_entries.hpp"
#include "server/cluster/pass_verdict.hpp"
#include "server/cluster/redis_layout.hpp"
#include "server/cluster/wire.hpp"

namespace tally::cluster {
namespace {

TEST(RedisLayout, StreamKeysParseBackAndOthersDoNot) {
  const PassKeys k("job7", "3.12", 41);
  EXPECT_EQ(k.stream, "tally:s:job7:3.12:41");
  EXPECT_EQ(k.meta, "tally:p:job7:3.12:41");
  EXPECT_EQ(k.index, "tally:r:job7:3.12:41");
  EXPECT_EQ(k.digests, "tally:d:job7:3.12:41");
  EXPECT_EQ(k.failures, "tally:f:job7:3.12:41");
  EXPECT_EQ(k.value(size_t{96}), "tally:v:job7:3.12:41:96");
  const auto s = parse_stream_key(k.stream);
  ASSERT_TRUE(s.has_value());
  EXPECT_EQ(s->id, "job7");
  EXPECT_EQ(s->run, "3.12");
  EXPECT_EQ(s->pass, 41u);
  for (const char* bad : {"tally:p:job7:3.12:41", "tally:s:job7:3.12:", "tally:s:job7:3.12:4x", "tally:s::1.1:2",
                          "tally:s:job7:3.12:-1", "tally:s:job7", "tally:s:job7:3.12:99999999999999999999"}) {
    EXPECT_FALSE(parse_stream_key(bad).has_value()) << bad;
  }
  EXPECT_EQ(active_key(""), "tally:active");
  EXPECT_EQ(active_key("big"), "tally:active:big");
}

TEST(PoolField, NamesAreShortAndPlain) {
  for (const char* ok : {"big", "gpu-2", "team_a.render", "X"}) EXPECT_TRUE(valid_pool_name(ok)) << ok;
  EXPECT_EQ(pool_name_problem(""), "must not be empty");
  EXPECT_EQ(pool_name_problem(std::string(65, 'a')), "must be at most 64 characters");
  EXPECT_TRUE(valid_pool_name(std::string(64, 'a')));
  for (const char* bad : {"a b", "a/b", "a:b", "a\"b", "ä"}) {
    EXPECT_EQ(pool_name_problem(bad), "may hold only letters, digits, '.', '_' and '-'") << bad;
  }
  EXPECT_EQ(spec_pool(nlohmann::json{{"kind", "integrate"}, {"pool", "big"}}), "big");
  EXPECT_EQ(spec_pool(nlohmann::json{{"kind", "integrate"}}), "");
}

// A pass of n one-sample blocks in groups of g.
PassWork pass_of(size_t n, size_t g, bool followed = false) {
  PassWork p;
  p.pass = 3;
  for (size_t i = 0; i < n; ++i) p.blocks.push_back(Block{i, i * 10, 10, 0});
  p.groups = result_groups(p.blocks, g);
  p.followed = followed;
  return p;
}

TEST(PassEntries, GuidedEntriesEndOnGroupsAndCoverThePass) {
  // 160 blocks in groups of 16, 2 threads, 1 ms per block: entries of at most 20 blocks
  // (20 ms) cut to whole groups (16), at least 2 blocks; 1/(2T) = 1/4 of what is left.
  const PassWork p = pass_of(160, 16);
  const EntryPlan plan = plan_entries(p, 2, 0.001, 4096, "j");
  EXPECT_EQ(plan.group_blocks, 16u);
  size_t next = 0;
  for (size_t e = 0; e < plan.entries.size(); ++e) {
    EXPECT_EQ(plan.entries[e].first, next);
    EXPECT_EQ(plan.entries[e].second % 16, 0u);
    EXPECT_EQ(plan.entry_groups[e], next / 16);
    EXPECT_EQ(plan.entry_at(next), e);
    next += plan.entries[e].second;
  }
  EXPECT_EQ(next, 160u);
  EXPECT_EQ(plan.entries.size(), 10u);  // 16 per entry: 20 ms holds one group of 16
  EXPECT_EQ(plan.entry_at(5), EntryPlan::npos);
  // No measured time yet: one group per entry.
  EXPECT_EQ(plan_entries(p, 2, 0, 4096, "j").entries.size(), 10u);
  // Single blocks, 0.1 ms each, 1 thread: 1/2 of what is left, capped at 200 (20 ms).
  const EntryPlan guided = plan_entries(pass_of(1000, 1), 1, 0.0001, 4096, "j");
  ASSERT_GE(guided.entries.size(), 3u);
  EXPECT_EQ(guided.entries[0].second, 200u);
  EXPECT_EQ(guided.entry_blocks, 200u);
  EXPECT_LT(guided.entries.back().second, 200u);
  // Followed by another pass: equal entries of 1/(2T) of the pass.
  const EntryPlan equal = plan_entries(pass_of(1000, 1, true), 1, 0.0001, 4096, "j");
  for (const auto& [first, count] : equal.entries) EXPECT_EQ(count, 200u) << first;
}

TEST(PassEntries, PublicationSkipsStoredEntries) {
  const PassWork p = pass_of(8, 2);
  const EntryPlan plan = plan_entries(p, 1, 0, 4096, "j");  // one group (2 blocks) per entry
  ASSERT_EQ(plan.entries.size(), 4u);
  size_t stored = 0;
  const PassPublication pub = publication(p, plan, {2, 6}, stored);
  EXPECT_EQ(stored, 4u);
  ASSERT_EQ(pub.new_entries.size(), 2u);
  EXPECT_EQ(pub.new_entries[0].first, "0");
  EXPECT_EQ(pub.new_entries[1].first, "4");
  EXPECT_EQ(decode_blocks(pub.new_entries[1].second), (std::vector<Block>{p.blocks[4], p.blocks[5]}));
  EXPECT_EQ(pub.blocks, 8u);
  EXPECT_EQ(pub.entries, 4u);
  EXPECT_EQ(pub.group_blocks, 2u);
}

TEST(PassEntries, DecodeChecksCountAndBlocks) {
  const PassWork p = pass_of(4, 2);
  const EntryPlan plan = plan_entries(p, 1, 0, 4096, "j");
  ASSERT_EQ(plan.entries.size(), 2u);
  auto result = [](uint64_t block) {
    BlockResult r;
    r.block_index = block;
    r.tallies.resize(1);
    return r;
  };
  std::string bytes;
  append_entry_result(bytes, encode_result(result(2)));
  std::vector<BlockResult> out;
  EXPECT_EQ(decode_entry(p, plan, 1, bytes, out), "");
  ASSERT_EQ(out.size(), 1u);
  EXPECT_EQ(out[0].block_index, 2u);
  EXPECT_EQ(decode_entry(p, plan, 0, bytes, out), "the result in slot 0 belongs to block 2, expected 0");
  std::string two = bytes;
  append_entry_result(two, encode_result(result(3)));
  EXPECT_EQ(decode_entry(p, plan, 1, two, out), "the entry at block slot 2 has 2 results, expected 1 (one per result group)");
  EXPECT_NE(decode_entry(p, plan, 1, "junk", out).find("cannot be decoded"), std::string::npos);
  // The group at slot 2 holds blocks 2 and 3, 10 samples each: a tally may count 20, not 21.
  BlockResult full = result(2);
  full.tallies.resize(3);
  full.first_channel = 4;
  full.tallies[2].n = 20;
  std::string ok;
  append_entry_result(ok, encode_result(full));
  EXPECT_EQ(decode_entry(p, plan, 1, ok, out), "");
  full.tallies[2].n = 21;
  std::string over;
  append_entry_result(over, encode_result(full));
  EXPECT_EQ(decode_entry(p, plan, 1, over, out),
            "the result of the group at block slot 2 counts 21 samples in channel 6, but its blocks hold 20: the "
            "results were changed or a worker is broken");
}

// The state of a pass of run 1.1 whose job hash was read: `stored` entries, stream there or not.
PassState state_of(long long stored, bool stream) {
  PassState st;
  st.job_hash_read = true;
  st.run = "1.1";
  st.entries_stored = stored;
  st.stream_exists = stream;
  return st;
}

TEST(PassVerdict, MarksBeforeCountsAndLostPassesRepublish) {
  PassState st = state_of(3, true);
  EXPECT_EQ(judge_pass(st, 4).what, PassVerdict::nothing);
  EXPECT_EQ(judge_pass(st, 3).what, PassVerdict::merge);
  st.mismatch = "7";
  const PassVerdict m = judge_pass(st, 3);
  EXPECT_EQ(m.what, PassVerdict::fail);
  EXPECT_NE(m.error.find("non-determinism"), std::string::npos);
  EXPECT_NE(m.error.find("slot 7"), std::string::npos);
  st.failed = "block 3 failed on w1";
  EXPECT_EQ(judge_pass(st, 3).error, "block 3 failed on w1");
  PassState lost;
  lost.job_hash_read = true;  // no run field: Redis lost the job
  EXPECT_EQ(judge_pass(lost, 1).what, PassVerdict::republish);
  EXPECT_EQ(judge_pass(state_of(0, false), 1).what, PassVerdict::republish);  // the stream is gone
}

TEST(PassVerdict, FlightCountsAndCrashLoops) {
  PassFlight f;
  f.entries_pending = 2;
  f.blocks_done = 10;
  f.redelivered = 1;
  const ExecutorStats::JobBlocks b = blocks_in_flight(f, 32, 8);
  EXPECT_EQ(b.in_flight, 16u);
  EXPECT_EQ(b.pending, 6u);
  EXPECT_EQ(b.redelivered, 1u);
  f.oldest = {{4, "w1/0"}};
  EXPECT_FALSE(crash_loop(f, 3).has_value());  // max_failures + 1 deliveries: one stall allowed
  f.oldest.push_back({5, "w2/0"});
  const auto c = crash_loop(f, 3);
  ASSERT_TRUE(c.has_value());
  EXPECT_NE(c->find("delivered 5 times"), std::string::npos) << *c;
  EXPECT_NE(c->find("w2/0"), std::string::npos) << *c;
}

}  // namespace
}  // namespace tally::cluster
