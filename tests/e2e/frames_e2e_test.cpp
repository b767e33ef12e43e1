// Production frames over the wire (issue 28): the real tally-server with its default
// limits admits a 1920x1080 image job, runs it to the end and stores its state; with --max-state-bytes
// below what the frame's state needs it refuses it with 422 naming the resolution, the
// bytes the state would need and the limit.
#include <SQLiteCpp/SQLiteCpp.h>
#include <gtest/gtest.h>

#include <string>

#include "client/sse_parser.hpp"
#include "server_process.hpp"
#include "tests/support/frame_scene.hpp"

namespace tally::e2e {
namespace {

using nlohmann::json;

// One pass of 4 samples a pixel (one per sobol replicate: an image's default K = 4),
// direct light only: a few seconds of work on two threads.
json frame_spec(int w, int h) { return scenes::frame_spec(w, h, 4); }

// The job's whole event stream, replayed from the start of its epoch (Last-Event-ID =
// epoch x 10^9; a new watcher of a finished job would get a snapshot without tiles). A
// pass over a frame refines every tile (60 x 34 of them at 1920x1080, over the 1,024
// events of the replay buffer): it publishes one `tiles` event naming them, no `tile`
// event each, so the whole stream is a few hundred bytes a pass.
void expect_one_tiles_event_a_pass(HttpClient& c, const std::string& id, int w, int h, uint64_t passes) {
  std::vector<SseEvent> snapshot, ev;
  size_t bytes = 0;
  auto read = [&](std::vector<SseEvent>& out, const std::string& last_id) {
    SseParser p([&](const SseEvent& e) { out.push_back(e); });
    HeaderList hl = {{"Accept", "text/event-stream"}};
    if (!last_id.empty()) hl.emplace_back("Last-Event-ID", last_id);
    const ClientResponse r = c.stream("/v1/jobs/" + id + "/events", hl,
                                      [&](std::string_view b) {
                                        bytes += b.size();
                                        p.feed(b);
                                        return out.empty() || out.back().event != "end";
                                      },
                                      60);
    ASSERT_EQ(r.status, 200) << r.body;
  };
  read(snapshot, "");
  ASSERT_FALSE(snapshot.empty());
  const uint64_t last = std::stoull(snapshot.back().id);
  bytes = 0;
  read(ev, std::to_string(last - last % 1'000'000'000ULL));
  ASSERT_FALSE(ev.empty());
  EXPECT_EQ(ev.back().event, "end");
  const int ts = 32;
  const uint64_t tiles = uint64_t((w + ts - 1) / ts) * uint64_t((h + ts - 1) / ts);
  uint64_t tiles_events = 0;
  for (const SseEvent& e : ev) {
    EXPECT_NE(e.event, "tile") << e.data;
    if (e.event != "tiles") continue;
    ++tiles_events;
    const json d = json::parse(e.data);
    EXPECT_EQ(d.at("count"), tiles) << e.data;
    EXPECT_EQ(d.at("first"), 0) << e.data;
    EXPECT_EQ(d.at("last"), tiles - 1) << e.data;
    EXPECT_EQ(d.at("x"), 0);
    EXPECT_EQ(d.at("y"), 0);
    EXPECT_EQ(d.at("w"), w);
    EXPECT_EQ(d.at("h"), h);
  }
  EXPECT_EQ(tiles_events, passes);
  EXPECT_LT(bytes, 2048 * (passes + 1)) << bytes << " bytes for " << ev.size() << " events";
}

TEST(FramesE2E, FullHdImageRunsWithDefaultLimits) {
  TempDir tmp;
  ServerProcess server(tmp.path / "data");
  HttpClient c = server.client(60);
  const std::string id = submit(c, frame_spec(1920, 1080));
  const json st = wait_state(c, id, "succeeded", 240);
  EXPECT_EQ(st.at("samples"), 4) << st.dump();
  EXPECT_EQ(st.at("passes"), 1) << st.dump();
  expect_one_tiles_event_a_pass(c, id, 1920, 1080, 1);
  server.kill9();
  // Its final state is stored in pieces: 1920 x 1080 x 12 sums of 4 bytes and the rest
  // (a frame's checkpoint may be over SQLite's 1e9-byte limit for one blob: a 4K frame's
  // was 1.6e9 bytes with 8-byte sums; a save in one blob used to fail with "string or
  // blob too big"; it is stored in pieces whatever its size).
  SQLite::Database db((tmp.path / "data" / "tally.db").string(), SQLite::OPEN_READONLY);
  SQLite::Statement q(db, "SELECT count(*), SUM(length(bytes)) FROM checkpoint_pieces WHERE id = ?");
  q.bind(1, id);
  ASSERT_TRUE(q.executeStep());
  EXPECT_GT(q.getColumn(0).getInt64(), 1);
  EXPECT_GT(q.getColumn(1).getInt64(), int64_t{1920} * 1080 * 12 * 4);
  EXPECT_LT(q.getColumn(1).getInt64(), int64_t{1920} * 1080 * 12 * 4 + (1 << 20));
}

TEST(FramesE2E, FrameOverMaxStateBytesIs422WithTheBytes) {
  TempDir tmp;
  ServerProcess server(tmp.path / "data", {"--max-state-bytes", "256MiB"});
  HttpClient c = server.client();
  const ClientResponse r =
      c.request("POST", "/v1/jobs", frame_spec(1920, 1080).dump(), {{"Content-Type", "application/json"}});
  EXPECT_EQ(r.status, 422) << r.body;
  EXPECT_EQ(r.header("Content-Type"), "application/problem+json");
  const json p = json::parse(r.body);
  EXPECT_EQ(p.at("pointer"), "/scene/camera/resolution") << r.body;
  // 3 x 4 x 1920 x 1080 sums of 4 + 8 bytes (the state's and a pass's results') + 2 x 60
  // x 34 tiles' counts of 8 bytes.
  EXPECT_EQ(p.at("detail"),
            "1920x1080 pixels x 3 colours x 4 replicates need 298631040 bytes of job state; the limit is 268435456 "
            "bytes")
      << r.body;
  EXPECT_EQ(get_json(c, "/v1/jobs").at("jobs").size(), 0u);
  // A frame within it is admitted.
  const std::string id = submit(c, frame_spec(640, 360));
  EXPECT_EQ(wait_state(c, id, "succeeded", 120).at("samples"), 4);
}

}  // namespace
}  // namespace tally::e2e
