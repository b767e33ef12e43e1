#include <gtest/gtest.h>

#include <algorithm>

#include "common/engine/checkpoint.hpp"
#include "integrate/run_support.hpp"

namespace tally {
namespace {

using nlohmann::json;

const json kSpecs[] = {
    {{"kind", "integrate"}, {"seed", 11}, {"integrand", {{"builtin", "unit_disk"}}}, {"stop", {{"max_samples", 3'000'001}}}},
    {{"kind", "integrate"}, {"seed", 12},
     {"integrand", {{"builtin", "genz"}, {"family", "oscillatory"}, {"a", {1.3, 2.1, 0.7}}, {"u", {0.3, 0.6, 0.45}}}},
     {"estimator", {{"type", "qmc"}, {"points", 512}}}, {"stop", {{"max_samples", 300}}}},
    {{"kind", "integrate"}, {"seed", 13}, {"integrand", {{"expression", "exp(-x0*x1)"}}},
     {"domain", {{"type", "disk"}}}, {"estimator", {{"type", "rejection"}}}, {"stop", {{"rel_error", 1e-4}}}},
    // Shifted lattice rules (issue 31): the shifts of a resumed job are the same draws.
    {{"kind", "integrate"}, {"seed", 14},
     {"integrand", {{"builtin", "genz"}, {"family", "gaussian"}, {"a", {1.3, 2.1, 0.7, 1.1, 0.9, 1.7, 0.5, 1.2}}}},
     {"estimator", {{"type", "lattice"}, {"points", 257}, {"periodize", "cubic"}}}, {"stop", {{"max_samples", 300}}}},
    // Higher-order (interlaced) nets: each randomization's scramble is the sample's own.
    {{"kind", "integrate"}, {"seed", 15},
     {"integrand", {{"builtin", "genz"}, {"family", "product_peak"}, {"a", {1.3, 2.1, 0.7, 1.1}}, {"u", {0.3, 0.6, 0.45, 0.5}}}},
     {"estimator", {{"type", "qmc"}, {"points", 256}, {"interlacing", 3}}}, {"stop", {{"max_samples", 300}}}},
};

using testing::expect_same_state;

TEST(Determinism, OneAndTwoThreadsGiveIdenticalBits) {
  for (const json& spec : kSpecs) {
    const auto one = testing::run_spec(spec, 1);
    const auto two = testing::run_spec(spec, 2);
    expect_same_state(one->state(), two->state());
  }
}

// Blocks run in any order on any thread: here in reverse, one at a time.
TEST(Determinism, BlockExecutionOrderDoesNotMatter) {
  const json& spec = kSpecs[0];
  const auto ref = testing::run_spec(spec, 1);
  auto job = compile_job(spec, JobLimits{});
  JobRunner r(job->kernel(), job->stop_rule(), JobCaps{});
  while (!r.finished()) {
    const auto blocks = r.plan_pass();
    std::vector<BlockResult> results(blocks.size());
    for (size_t i = blocks.size(); i-- > 0;) {
      results[i].block_index = blocks[i].index;
      r.kernel().run_block(blocks[i], results[i]);
    }
    r.commit_pass(std::move(results), 0.01);
  }
  expect_same_state(ref->state(), r.state());
}

// A job checkpointed at any pass boundary and resumed ends bit-identical to an
// uninterrupted run.
TEST(Determinism, ResumeFromCheckpointIsBitIdentical) {
  for (const json& spec : kSpecs) {
    const auto ref = testing::run_spec(spec, 2);
    for (uint64_t stop_after : {1, 2, 5}) {
      const testing::Interrupted first = testing::run_until_pass(spec, stop_after);
      if (first.checkpoint.empty()) continue;  // finished before that pass
      expect_same_state(ref->state(), testing::resume_spec(spec, decode_checkpoint(first.checkpoint))->state());
    }
  }
}

TEST(Determinism, DifferentSeedsDiffer) {
  json a = kSpecs[0], b = kSpecs[0];
  b["seed"] = 99;
  EXPECT_NE(testing::run_spec(a)->state().channels[0].mean, testing::run_spec(b)->state().channels[0].mean);
}

}  // namespace
}  // namespace tally
