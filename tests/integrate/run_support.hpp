#pragma once
// Runs a job spec through the production path: compile_job -> JobRunner -> run_local;
// interrupts one at a pass boundary with its checkpoint, resumes it, and compares states.
#include <gtest/gtest.h>

#include <atomic>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "common/engine/checkpoint.hpp"
#include "common/engine/pass_loop.hpp"
#include "common/integrate/integration_counters.hpp"
#include "common/protocol/job_kinds.hpp"
#include "common/spec/spec_reader.hpp"

namespace tally::testing {

struct Ran {
  std::unique_ptr<JobDefinition> job;
  std::unique_ptr<JobRunner> runner;
  const JobRunner* operator->() const { return runner.get(); }
};

inline Ran run_spec(const nlohmann::json& spec, unsigned threads = 1) {
  Ran r;
  r.job = compile_job(spec, JobLimits{});
  r.runner = std::make_unique<JobRunner>(r.job->kernel(), r.job->stop_rule(), JobCaps{});
  run_local(*r.runner, threads);
  return r;
}

// A run of `spec` on 2 threads cancelled at the end of pass `stop_after`, and the
// checkpoint taken there ("" if the job finished before that pass).
struct Interrupted {
  Ran run;
  std::string checkpoint;
};

inline Interrupted run_until_pass(const nlohmann::json& spec, uint64_t stop_after) {
  Interrupted out;
  out.run.job = compile_job(spec, JobLimits{});
  out.run.runner = std::make_unique<JobRunner>(out.run.job->kernel(), out.run.job->stop_rule(), JobCaps{});
  std::atomic<bool> cancel{false};
  LocalRunOptions o;
  o.threads = 2;
  o.cancel = &cancel;
  o.on_pass = [&](const JobRunner& jr) {
    if (jr.state().passes == stop_after) {
      out.checkpoint = encode_checkpoint(jr.state());
      cancel = true;
    }
  };
  run_local(*out.run.runner, o);
  return out;
}

// `spec` resumed from `state` (a decoded checkpoint) and run to its end.
inline Ran resume_spec(const nlohmann::json& spec, JobState state, unsigned threads = 1) {
  Ran r;
  r.job = compile_job(spec, JobLimits{});
  r.runner = std::make_unique<JobRunner>(r.job->kernel(), r.job->stop_rule(), JobCaps{}, std::move(state));
  run_local(*r.runner, threads);
  return r;
}

// The spec's domain [0, 1]^d.
inline nlohmann::json unit_box(size_t d) {
  return {{"type", "box"}, {"lower", std::vector<double>(d, 0.0)}, {"upper", std::vector<double>(d, 1.0)}};
}

// The JSON pointer compile_job's SpecError names for `spec`, or "<accepted>".
inline std::string spec_error_pointer(const nlohmann::json& spec) {
  try {
    compile_job(spec, JobLimits{});
  } catch (const SpecError& e) {
    return e.pointer();
  }
  return "<accepted>";
}

// Every part of two runs' states that a deterministic job reproduces bit for bit.
inline void expect_same_state(const JobState& a, const JobState& b) {
  ASSERT_EQ(a.channels.size(), b.channels.size());
  for (size_t i = 0; i < a.channels.size(); ++i) EXPECT_EQ(a.channels[i], b.channels[i]) << i;
  EXPECT_EQ(a.samples, b.samples);
  EXPECT_EQ(a.passes, b.passes);
  EXPECT_EQ(a.counters, b.counters);
  EXPECT_EQ(a.tail.sorted_values(), b.tail.sorted_values());
  EXPECT_EQ(a.kernel_state, b.kernel_state);  // e.g. the VEGAS grid and every iteration
}

}  // namespace tally::testing
