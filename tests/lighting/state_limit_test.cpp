// The lighting spec reader's limit on a job's state in bytes (JobLimits::max_state_bytes,
// job_state_bytes): 1920x1080 and 3840x2160 frames fit half of a 24 GB machine (what
// tally-server and `tally run` take by default); a frame over the limit is refused
// naming /scene/camera/resolution, the bytes it would need and the limit.
#include <gtest/gtest.h>

#include <nlohmann/json.hpp>
#include <string>

#include "common/engine/job_state.hpp"
#include "common/engine/limits.hpp"
#include "common/lighting/lighting_spec.hpp"
#include "common/spec/spec_reader.hpp"
#include "tests/support/frame_scene.hpp"

namespace tally {
namespace {

using nlohmann::json;

json frame_spec(int w, int h) { return scenes::frame_spec(w, h, 8); }

// Half of 24 GB, what default_memory_budget() gives on this project's reference machine.
constexpr uint64_t kHalfOf24GB = 12ULL << 30;

TEST(StateLimit, FullHdAndFourKFitHalfOf24GB) {
  // 3 colours x 4 replicates (an image's default) x (a 4-byte sum in the state + an
  // 8-byte one in a pass's results) + 8 bytes a 32-pixel tile, twice.
  EXPECT_EQ(job_state_bytes(0, 60 * 34, uint64_t{3} * 4 * 1920 * 1080), 298631040ULL);
  EXPECT_EQ(job_state_bytes(0, 120 * 68, uint64_t{3} * 4 * 3840 * 2160), 1194524160ULL);
  JobLimits limits;
  limits.max_state_bytes = kHalfOf24GB;
  for (const auto& [w, h] : {std::pair{1920, 1080}, std::pair{3840, 2160}}) {
    const auto def = compile_lighting_job(frame_spec(w, h), limits);
    EXPECT_EQ(def->kernel()->channel_count(), 0u);
    EXPECT_EQ(def->kernel()->sum_count(), uint64_t{3} * 4 * w * h);
  }
}

TEST(StateLimit, IndependentSamplesKeepATallyPerChannel) {
  // K = 1: the error bar is the samples' own variance, so a pixel keeps 3 tallies of 24
  // bytes: 2 x (3 x 24 x 3840 x 2160 + 8 x 120 x 68).
  json spec = frame_spec(3840, 2160);
  spec["sampler"] = "independent";
  JobLimits limits;
  limits.max_state_bytes = 1194524160ULL - 1;
  try {
    compile_lighting_job(spec, limits);
    FAIL() << "a 4K frame over the state limit was accepted";
  } catch (const SpecError& e) {
    EXPECT_EQ(e.pointer(), "/scene/camera/resolution");
    EXPECT_EQ(e.detail(),
              "3840x2160 pixels x 3 colours x 1 replicates need 1194524160 bytes of job state; the limit is "
              "1194524159 bytes");
  }
  limits.max_state_bytes = 1194524160ULL;
  const auto def = compile_lighting_job(spec, limits);
  EXPECT_EQ(def->kernel()->channel_count(), uint64_t{3} * 3840 * 2160);
  EXPECT_EQ(def->kernel()->sum_count(), 0u);
}

TEST(StateLimit, FrameOverTheLimitNamesResolutionAndBytes) {
  JobLimits limits;
  limits.max_state_bytes = 1194524160ULL - 1;  // one byte short of the 4K frame's state
  try {
    compile_lighting_job(frame_spec(3840, 2160), limits);
    FAIL() << "a 4K frame over the state limit was accepted";
  } catch (const SpecError& e) {
    EXPECT_EQ(e.pointer(), "/scene/camera/resolution");
    EXPECT_EQ(e.detail(),
              "3840x2160 pixels x 3 colours x 4 replicates need 1194524160 bytes of job state; the limit is "
              "1194524159 bytes");
  }
  limits.max_state_bytes = 1194524160ULL;  // exactly at the limit is fine
  EXPECT_NO_THROW(compile_lighting_job(frame_spec(3840, 2160), limits));
}

TEST(StateLimit, PointsOverTheLimitNameThePoints) {
  json spec = frame_spec(1, 1);
  spec["scene"].erase("camera");
  const json point = {{"p", {0, 0, 0}}, {"n", {0, 0, 1}}, {"material", "white"}};
  spec["query"] = {{"type", "points"}, {"points", json::array({point, point})}};
  JobLimits limits;
  // 2 points x 1 estimator x 3 colours x 8 replicates = 48 tallies and 1 partition, twice.
  limits.max_state_bytes = 2 * (48 * 24 + 8) - 1;
  try {
    compile_lighting_job(spec, limits);
    FAIL() << "points over the state limit were accepted";
  } catch (const SpecError& e) {
    EXPECT_EQ(e.pointer(), "/query/points");
    EXPECT_EQ(e.detail(),
              "2 points x 1 estimators x 3 colours x 8 replicates need 2320 bytes of job state; the limit is 2319 bytes");
  }
  limits.max_state_bytes = 2320;
  EXPECT_NO_THROW(compile_lighting_job(spec, limits));
}

}  // namespace
}  // namespace tally
