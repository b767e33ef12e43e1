#include "common/engine/job_runner.hpp"

#include <gtest/gtest.h>

#include <atomic>
#include <bit>
#include <cmath>

#include "common/engine/checkpoint.hpp"
#include "common/engine/pass_loop.hpp"
#include "common/rng/counter_rng.hpp"

namespace tally {
namespace {

// A kernel whose samples are U(0,1): mean 1/2, variance 1/12.
class UniformValues final : public Kernel {
 public:
  size_t channel_count() const override { return 1; }
  PassSchedule schedule() const override { return {1000, 64000, 500}; }
  void run_block(const Block& b, BlockResult& out) const override {
    const uint64_t key = stream_key(9, 0);
    Tally t;
    for (uint64_t i = 0; i < b.sample_count; ++i) t.add(SampleRng(key, b.first_sample + i).uniform(0));
    out.tallies = {t};
  }
};

// The same with passes in multiples of 8 (as K randomized-QMC replicates need).
class QuantizedUniformValues final : public Kernel {
 public:
  size_t channel_count() const override { return 1; }
  PassSchedule schedule() const override {
    PassSchedule s{1000, 64000, 496};
    s.sample_quantum = 8;
    return s;
  }
  void run_block(const Block& b, BlockResult& out) const override { UniformValues().run_block(b, out); }
};

TEST(JobRunner, PassesAreMultiplesOfTheSampleQuantumUnlessALimitCuts) {
  StopRule rule;
  rule.abs_error = 1e-3;  // passes aimed at the predicted need: arbitrary sizes before rounding
  JobRunner r(std::make_shared<QuantizedUniformValues>(), rule, JobCaps{});
  std::vector<uint64_t> sizes;
  LocalRunOptions o;
  uint64_t last = 0;
  o.on_pass = [&](const JobRunner& j) {
    sizes.push_back(j.state().samples - last);
    last = j.state().samples;
  };
  run_local(r, o);
  EXPECT_EQ(r.stop_reason(), StopReason::error_target);
  ASSERT_GT(sizes.size(), 2u);
  for (uint64_t n : sizes) EXPECT_EQ(n % 8, 0u) << n;
  // A sample limit wins over the quantum: the job stops exactly there.
  StopRule cap;
  cap.max_samples = 12345;
  JobRunner c(std::make_shared<QuantizedUniformValues>(), cap, JobCaps{});
  run_local(c, 2);
  EXPECT_EQ(c.state().samples, 12345u);
}

// Three partitions, passes in multiples of 8, planned from counts alone.
class CountPlannedValues final : public Kernel {
 public:
  size_t channel_count() const override { return 1; }
  uint32_t partition_count() const override { return 3; }
  PassSchedule schedule() const override {
    PassSchedule s{1000, 64000, 496};
    s.sample_quantum = 8;
    return s;
  }
  bool plans_from_counts() const override { return planned_from_counts; }
  void run_block(const Block& b, BlockResult& out) const override { UniformValues().run_block(b, out); }
  bool planned_from_counts = true;
};

std::vector<BlockResult> run_blocks(const Kernel& k, const std::vector<Block>& blocks) {
  std::vector<BlockResult> out(blocks.size());
  for (size_t i = 0; i < blocks.size(); ++i) {
    out[i].block_index = blocks[i].index;
    k.run_block(blocks[i], out[i]);
  }
  return out;
}

// A cluster publishes the pass plan_ahead gives before the pass before it is merged:
// it must be exactly the pass plan_pass returns after that commit, and there must be
// none when the job stops there.
TEST(JobRunner, PlanAheadIsThePassPlannedAfterTheCommit) {
  for (uint64_t max : {300'001ull, 128'000ull, 999ull}) {
    StopRule rule;
    rule.max_samples = max;
    auto kernel = std::make_shared<CountPlannedValues>();
    JobRunner r(kernel, rule, JobCaps{});
    std::vector<Block> pass = r.plan_pass();
    size_t passes = 0, ahead_count = 0;
    while (!pass.empty()) {
      bool followed = true;
      const std::optional<std::vector<Block>> ahead = r.plan_ahead(&followed);
      r.commit_pass(run_blocks(*kernel, pass), 0.01);
      ++passes;
      pass = r.plan_pass();
      if (ahead) {
        ++ahead_count;
        EXPECT_TRUE(*ahead == pass) << "max " << max << ", after pass " << passes;
        // `followed` foretells whether the pass after this one can be planned ahead too.
        EXPECT_EQ(followed, r.plan_ahead().has_value()) << "max " << max << ", after pass " << passes;
      } else {
        EXPECT_FALSE(followed);
        EXPECT_TRUE(pass.empty()) << "max " << max << ": nothing planned ahead, yet pass " << passes + 1 << " came";
      }
    }
    EXPECT_EQ(r.state().samples, max);
    EXPECT_EQ(ahead_count + 1, passes) << "every pass but the last is planned ahead";
  }
}

TEST(JobRunner, NothingIsPlannedAheadWhenResultsCanChangeThePlan) {
  auto kernel = std::make_shared<CountPlannedValues>();
  StopRule target;
  target.abs_error = 1e-3;  // pass sizes follow the error
  JobRunner a(kernel, target, JobCaps{});
  a.plan_pass();
  EXPECT_FALSE(a.plan_ahead());
  StopRule budget;
  budget.time_budget_s = 10;  // pass sizes follow the measured rate
  JobRunner b(kernel, budget, JobCaps{});
  b.plan_pass();
  EXPECT_FALSE(b.plan_ahead());
  auto adaptive = std::make_shared<CountPlannedValues>();
  adaptive->planned_from_counts = false;  // e.g. VEGAS, adaptive image tiles
  StopRule count;
  count.max_samples = 1'000'000;
  JobRunner c(adaptive, count, JobCaps{});
  c.plan_pass();
  EXPECT_FALSE(c.plan_ahead());
  JobRunner d(kernel, count, JobCaps{});
  EXPECT_FALSE(d.plan_ahead()) << "no pass planned yet";
  d.plan_pass();
  EXPECT_TRUE(d.plan_ahead());
}

// Three tiles of two channels whose values span magnitudes (so the order of merging
// shows in the last bits), results combined 3 blocks at a time.
class GroupedTiles final : public Kernel {
 public:
  size_t channel_count() const override { return 6; }
  uint32_t partition_count() const override { return 3; }
  PassSchedule schedule() const override {
    PassSchedule s{250, 4000, 100};
    s.group_blocks = 3;
    return s;
  }
  bool plans_from_counts() const override { return true; }
  void run_block(const Block& b, BlockResult& out) const override {
    const uint64_t key = stream_key(11, b.partition);
    out.first_channel = 2 * b.partition;
    out.tallies.assign(2, Tally{});
    for (uint64_t i = 0; i < b.sample_count; ++i) {
      SampleRng rng(key, b.first_sample + i);
      const double v = std::exp(8.0 * rng.uniform(0)) * (1.0 + b.partition);
      out.tallies[0].add(v);
      out.tallies[1].add(1.0 / v);
      out.tail.offer(v);
      out.weights.add(rng.uniform(1));
    }
  }
};

TEST(ResultGroups, CutAtTheGroupSizeAndWherePartitionsChange) {
  std::vector<Block> blocks;
  for (uint32_t p : {0u, 0u, 0u, 0u, 0u, 1u, 1u, 2u, 2u, 2u, 2u, 2u, 2u, 2u, 2u, 2u}) {
    blocks.push_back(Block{blocks.size(), 0, 1, p});
  }
  const std::vector<ResultGroup> want = {{0, 4}, {4, 1}, {5, 2}, {7, 4}, {11, 4}, {15, 1}};
  EXPECT_EQ(result_groups(blocks, 4), want);
  EXPECT_EQ(result_groups(blocks, 1).size(), blocks.size());
  EXPECT_EQ(result_groups(blocks, 0).size(), blocks.size()) << "0 means 1";
  // A run of whole groups (a cluster entry) cut alone gives the same groups.
  for (size_t a = 0; a < want.size(); ++a) {
    for (size_t b = a + 1; b <= want.size(); ++b) {
      const size_t first = want[a].first, end = want[b - 1].first + want[b - 1].count;
      const std::vector<ResultGroup> part =
          result_groups(std::span<const Block>(blocks).subspan(first, end - first), 4);
      ASSERT_EQ(part.size(), b - a);
      for (size_t i = 0; i < part.size(); ++i) {
        EXPECT_EQ(part[i].first + first, want[a + i].first);
        EXPECT_EQ(part[i].count, want[a + i].count);
      }
    }
  }
}

TEST(JobRunner, ResultsCombinedWhereTheBlocksRanGiveTheSameBits) {
  // What a cluster worker does (combine each group's results, send one per group) and
  // what commit_pass does with per-block results must be the same arithmetic.
  auto kernel = std::make_shared<GroupedTiles>();
  StopRule rule;
  rule.max_samples = 9000;
  JobRunner a(kernel, rule, JobCaps{}), b(kernel, rule, JobCaps{});
  Tally per_block;  // channel 0 merged block by block, as before result groups
  size_t passes = 0, grouped = 0;
  for (std::vector<Block> pass = a.plan_pass(); !pass.empty(); pass = a.plan_pass()) {
    ASSERT_EQ(b.plan_pass(), pass);
    ASSERT_EQ(a.result_groups(), b.result_groups());
    std::vector<BlockResult> results = run_blocks(*kernel, pass);
    for (size_t i = 0; i < pass.size(); ++i) {
      if (pass[i].partition == 0) per_block.merge(results[i].tallies[0]);
    }
    std::vector<BlockResult> combined;
    for (const ResultGroup& g : b.result_groups()) {
      BlockResult acc = results[g.first];
      for (size_t i = g.first + 1; i < g.first + g.count; ++i) combine_results(acc, results[i]);
      EXPECT_EQ(acc.block_index, pass[g.first].index);
      combined.push_back(std::move(acc));
      grouped += g.count > 1;
    }
    a.commit_pass(std::move(results), 0.01);
    b.commit_groups(std::move(combined), 0.01);
    ++passes;
  }
  EXPECT_GT(passes, 3u);
  EXPECT_GT(grouped, 10u) << "most groups hold several blocks";
  EXPECT_EQ(a.state().samples, 9000u);
  EXPECT_EQ(encode_checkpoint(a.state()), encode_checkpoint(b.state())) << "bit-identical states";
  // The grouping is in effect: merging block by block rounds differently.
  const Tally& t = a.state().channels[0];
  EXPECT_EQ(t.n, per_block.n);
  EXPECT_NEAR(t.mean, per_block.mean, 1e-12 * std::fabs(t.mean));
  EXPECT_FALSE(t == per_block) << "groups of 3 combine before they merge";
}

// merge_group, group by group in order, then finish_pass: the bits of commit_groups. In
// between, the state holds the merged groups with their partitions' samples counted,
// and the pass's totals (passes, samples) wait for finish_pass. run_local merges that
// way from 1 and from 3 threads to the same bits.
TEST(JobRunner, GroupsMergedOneByOneGiveCommitGroupsBits) {
  auto kernel = std::make_shared<GroupedTiles>();
  StopRule rule;
  rule.max_samples = 9000;
  JobRunner a(kernel, rule, JobCaps{}), b(kernel, rule, JobCaps{});
  bool checked_midway = false;
  for (std::vector<Block> pass = a.plan_pass(); !pass.empty(); pass = a.plan_pass()) {
    ASSERT_EQ(b.plan_pass(), pass);
    std::vector<BlockResult> per_block = run_blocks(*kernel, pass);
    std::vector<BlockResult> grouped = combine_groups(std::move(per_block), a.result_groups());
    std::vector<BlockResult> copy = grouped;
    const std::vector<ResultGroup> groups = b.result_groups();
    a.commit_groups(std::move(grouped), 0.01);
    const JobState before = b.state();
    for (size_t g = 0; g < copy.size(); ++g) {
      b.merge_group(std::move(copy[g]));
      EXPECT_EQ(b.groups_merged(), g + 1);
      if (g == 0 && groups.size() > 1 && !checked_midway) {
        checked_midway = true;
        const uint32_t p = pass[groups[0].first].partition;
        uint64_t n = 0;
        for (size_t i = 0; i < groups[0].count; ++i) n += pass[groups[0].first + i].sample_count;
        EXPECT_EQ(b.state().partition_samples[p], before.partition_samples[p] + n) << "counted with its group";
        EXPECT_EQ(b.state().samples, before.samples) << "the pass's total moves at finish_pass";
        EXPECT_EQ(b.state().passes, before.passes);
      }
    }
    b.finish_pass(0.01);
  }
  EXPECT_TRUE(checked_midway);
  EXPECT_EQ(encode_checkpoint(a.state()), encode_checkpoint(b.state())) << "bit-identical states";
  JobRunner one(kernel, rule, JobCaps{}), three(kernel, rule, JobCaps{});
  run_local(one, 1);
  run_local(three, 3);
  // The trace records compute time; everything else is the same bits.
  JobState x = one.state(), y = three.state(), z = a.state();
  x.trace.clear(), y.trace.clear(), z.trace.clear();
  x.compute_seconds = y.compute_seconds = z.compute_seconds = 0;
  EXPECT_EQ(encode_checkpoint(x), encode_checkpoint(z));
  EXPECT_EQ(encode_checkpoint(y), encode_checkpoint(z));
}

// A cancel raised while a pass runs: run_pass returns false, the groups merged by then
// stay merged with their counts (every partition consistent), the rest are dropped.
TEST(JobRunner, CancelledPassKeepsWhatItMergedConsistent) {
  auto kernel = std::make_shared<GroupedTiles>();
  StopRule rule;
  rule.max_samples = 9000;
  JobRunner r(kernel, rule, JobCaps{});
  const std::vector<Block> pass = r.plan_pass();
  std::atomic<bool> cancel{true};
  EXPECT_FALSE(run_pass(r, pass, 2, &cancel));
  r.cancel();
  EXPECT_EQ(r.stop_reason(), StopReason::cancelled);
  for (uint32_t p = 0; p < 3; ++p) {
    EXPECT_EQ(r.state().channels[2 * p].n, r.state().partition_samples[p]) << p;
  }
}

// Sum channels are floats in the state and doubles in a result: each merge adds in
// double and rounds once (JobState::sums), so m merges are within m roundings of 2^-24
// of the exact sum, however many samples each holds. 4000 passes of 1000 samples of
// 0.1: a float accumulated sample by sample would be off by about 3%; this is within
// 4000 x 2^-24 (2.4e-4) and in practice far closer.
class TenthsInSums final : public Kernel {
 public:
  size_t channel_count() const override { return 0; }
  size_t sum_count() const override { return 1; }
  PassSchedule schedule() const override { return {1000, 1000, 1000}; }
  void run_block(const Block& b, BlockResult& out) const override {
    double s = 0;
    for (uint64_t i = 0; i < b.sample_count; ++i) s += 0.1;
    out.sums = {s};
  }
  ErrorSummary error_summary(const JobState&, double) const override { return {}; }
  std::vector<ComponentError> component_errors(const JobState&, double) const override { return {}; }
};

TEST(JobRunner, SumChannelsRoundOncePerMerge) {
  StopRule rule;
  rule.max_samples = 4'000'000;
  JobRunner r(std::make_shared<TenthsInSums>(), rule, JobCaps{});
  run_local(r, 1);
  ASSERT_EQ(r.state().passes, 4000u);
  const double exact = 0.1 * 4e6;
  const double rel = std::fabs(static_cast<double>(r.state().sums[0]) - exact) / exact;
  EXPECT_LE(rel, 4000 * std::ldexp(1.0, -24)) << rel;
  float naive = 0;
  for (int i = 0; i < 4'000'000; ++i) naive += 0.1f;
  EXPECT_GT(std::fabs(static_cast<double>(naive) - exact) / exact, 100 * rel) << "what the double results avoid";
}

// error() is computed once per state and rule, not per call: it must equal the kernel's
// summary of the current state at the current confidence after construction, every
// commit, an extend that changes the confidence, and a resume from a checkpoint.
TEST(JobRunner, CachedErrorSummaryIsTheKernelsOfTheCurrentState) {
  auto kernel = std::make_shared<UniformValues>();
  auto same = [&](const JobRunner& r) {
    const ErrorSummary want = kernel->error_summary(r.state(), r.rule().confidence);
    const ErrorSummary& got = r.error();
    return std::bit_cast<uint64_t>(got.abs_error) == std::bit_cast<uint64_t>(want.abs_error) &&
           std::bit_cast<uint64_t>(got.rel_error) == std::bit_cast<uint64_t>(want.rel_error) &&
           std::bit_cast<uint64_t>(got.sigma) == std::bit_cast<uint64_t>(want.sigma) &&
           std::bit_cast<uint64_t>(got.mean) == std::bit_cast<uint64_t>(want.mean);
  };
  StopRule rule;
  rule.max_samples = 20000;
  rule.confidence = 0.95;
  JobRunner r(kernel, rule, JobCaps{});
  EXPECT_TRUE(same(r));
  size_t passes = 0;
  for (std::vector<Block> pass = r.plan_pass(); !pass.empty(); pass = r.plan_pass()) {
    r.commit_pass(run_blocks(*kernel, pass), 0.01);
    EXPECT_TRUE(same(r)) << "after pass " << passes;
    ++passes;
  }
  EXPECT_GT(passes, 2u);
  const double half_width_95 = r.error().abs_error;
  StopRule wider = rule;
  wider.max_samples = 40000;
  wider.confidence = 0.99;
  r.extend(wider);
  EXPECT_TRUE(same(r));
  EXPECT_GT(r.error().abs_error, half_width_95) << "a 99% interval is wider than a 95% one";
  JobRunner resumed(kernel, wider, JobCaps{}, r.state());
  EXPECT_TRUE(same(resumed));
}

TEST(JobRunner, MaxSamplesStopsExactly) {
  StopRule rule;
  rule.max_samples = 12345;
  JobRunner r(std::make_shared<UniformValues>(), rule, JobCaps{});
  run_local(r, 2);
  EXPECT_EQ(r.stop_reason(), StopReason::max_samples);
  EXPECT_EQ(r.state().samples, 12345u);
  EXPECT_EQ(r.state().channels[0].n, 12345u);
}

TEST(JobRunner, ErrorTargetStopsWhenMet) {
  StopRule rule;
  rule.abs_error = 1e-3;
  JobRunner r(std::make_shared<UniformValues>(), rule, JobCaps{});
  run_local(r, 1);
  EXPECT_EQ(r.stop_reason(), StopReason::error_target);
  EXPECT_TRUE(r.target_met());
  EXPECT_LE(r.error().abs_error, 1e-3);
  // (1.96 * sqrt(1/12) / 1e-3)^2 = 320,110 samples needed; the planner aims passes at
  // the predicted need, so it should not overshoot by more than a pass's headroom.
  EXPECT_GT(r.state().samples, 300'000u);
  EXPECT_LT(r.state().samples, 420'000u);
}

TEST(JobRunner, CapStopsJobsWithoutOtherLimits) {
  StopRule rule;
  rule.rel_error = 1e-12;  // unreachable
  JobCaps caps;
  caps.max_samples = 50'000;
  JobRunner r(std::make_shared<UniformValues>(), rule, caps);
  run_local(r, 2);
  EXPECT_EQ(r.stop_reason(), StopReason::sample_cap);
  EXPECT_FALSE(r.target_met());
  EXPECT_EQ(r.state().samples, 50'000u);
}

TEST(JobRunner, PredictionMatchesClosedForm) {
  StopRule rule;
  rule.abs_error = 1e-4;
  rule.max_samples = 100'000;
  JobRunner r(std::make_shared<UniformValues>(), rule, JobCaps{});
  run_local(r, 1);
  const auto p = r.prediction();
  ASSERT_TRUE(p.has_value());
  const double expect = std::pow(1.959963985 * std::sqrt(1.0 / 12.0) / 1e-4, 2);
  EXPECT_NEAR(p->samples_needed, expect, 0.02 * expect);  // sigma estimated from 1e5 samples
}

TEST(JobRunner, ExtendReopensAFinishedJob) {
  StopRule rule;
  rule.max_samples = 5000;
  JobRunner r(std::make_shared<UniformValues>(), rule, JobCaps{});
  run_local(r, 1);
  ASSERT_TRUE(r.finished());
  rule.max_samples = 20000;
  r.extend(rule);
  EXPECT_FALSE(r.finished());
  run_local(r, 1);
  EXPECT_EQ(r.state().samples, 20000u);
}

TEST(JobRunner, CancelStopsAtPassBoundary) {
  StopRule rule;
  rule.max_samples = 1'000'000;
  JobRunner r(std::make_shared<UniformValues>(), rule, JobCaps{});
  std::atomic<bool> cancel{false};
  LocalRunOptions o;
  o.threads = 1;
  o.cancel = &cancel;
  o.on_pass = [&](const JobRunner& jr) {
    if (jr.state().passes == 2) cancel = true;
  };
  run_local(r, o);
  EXPECT_EQ(r.stop_reason(), StopReason::cancelled);
  EXPECT_EQ(r.state().passes, 2u);
}

}  // namespace
}  // namespace tally
