// Production frames over the wire (issue 28): the real tally-server with its default
// limits admits a 1920x1080 image job, runs it to the end and stores its state; with --max-state-bytes
// below what the frame's state needs it refuses it with 422 naming the resolution, the
// bytes the state would need and the limit.
#include <SQLiteCpp/SQLiteCpp.h>
#include <gtest/gtest.h>

#include <string>

#include "server_process.hpp"
#include "tests/support/frame_scene.hpp"

namespace tally::e2e {
namespace {

using nlohmann::json;

// One pass of 8 samples a pixel (one per sobol replicate), direct light only: a few
// seconds of work on two threads.
json frame_spec(int w, int h) { return scenes::frame_spec(w, h, 8); }

TEST(FramesE2E, FullHdImageRunsWithDefaultLimits) {
  TempDir tmp;
  ServerProcess server(tmp.path / "data");
  HttpClient c = server.client(60);
  const std::string id = submit(c, frame_spec(1920, 1080));
  const json st = wait_state(c, id, "succeeded", 240);
  EXPECT_EQ(st.at("samples"), 8) << st.dump();
  EXPECT_EQ(st.at("passes"), 1) << st.dump();
  server.kill9();
  // Its final state is stored in pieces: 1920 x 1080 x 24 sums of 4 bytes and the rest
  // (a frame's checkpoint may be over SQLite's 1e9-byte limit for one blob: a 4K frame's
  // was 1.6e9 bytes with 8-byte sums; a save in one blob used to fail with "string or
  // blob too big"; it is stored in pieces whatever its size).
  SQLite::Database db((tmp.path / "data" / "tally.db").string(), SQLite::OPEN_READONLY);
  SQLite::Statement q(db, "SELECT count(*), SUM(length(bytes)) FROM checkpoint_pieces WHERE id = ?");
  q.bind(1, id);
  ASSERT_TRUE(q.executeStep());
  EXPECT_GT(q.getColumn(0).getInt64(), 1);
  EXPECT_GT(q.getColumn(1).getInt64(), int64_t{1920} * 1080 * 24 * 4);
  EXPECT_LT(q.getColumn(1).getInt64(), int64_t{1920} * 1080 * 24 * 4 + (1 << 20));
}

TEST(FramesE2E, FrameOverMaxStateBytesIs422WithTheBytes) {
  TempDir tmp;
  ServerProcess server(tmp.path / "data", {"--max-state-bytes", "512MiB"});
  HttpClient c = server.client();
  const ClientResponse r =
      c.request("POST", "/v1/jobs", frame_spec(1920, 1080).dump(), {{"Content-Type", "application/json"}});
  EXPECT_EQ(r.status, 422) << r.body;
  EXPECT_EQ(r.header("Content-Type"), "application/problem+json");
  const json p = json::parse(r.body);
  EXPECT_EQ(p.at("pointer"), "/scene/camera/resolution") << r.body;
  // 3 x 8 x 1920 x 1080 sums of 4 + 8 bytes (the state's and a pass's results') + 2 x 60
  // x 34 tiles' counts of 8 bytes.
  EXPECT_EQ(p.at("detail"),
            "1920x1080 pixels x 3 colours x 8 replicates need 597229440 bytes of job state; the limit is 536870912 "
            "bytes")
      << r.body;
  EXPECT_EQ(get_json(c, "/v1/jobs").at("jobs").size(), 0u);
  // A frame within it is admitted.
  const std::string id = submit(c, frame_spec(640, 360));
  EXPECT_EQ(wait_state(c, id, "succeeded", 120).at("samples"), 8);
}

}  // namespace
}  // namespace tally::e2e
