// A store that fails (a full disk, a read-only volume): with the data dir full, 40
// POSTs all got 202, /readyz stayed 200, and after a restart 7 of 40 jobs existed.
// Now a job is acknowledged only once stored; while the store fails, submissions get
// 503 naming the cause, /readyz is 503, failures are counted in /metrics, and
// checkpoints and final states are retried until they are stored.
#include <gtest/gtest.h>

#include <atomic>
#include <condition_variable>
#include <functional>
#include <future>
#include <mutex>
#include <thread>

#include "common/protocol/job_json.hpp"
#include "gated_store.hpp"
#include "server_test_support.hpp"

namespace tally::test {
namespace {

using nlohmann::json;

// Wraps a store; while `failing`, every save throws (as SQLite does on a full disk).
class FailingStore final : public JobStore {
 public:
  explicit FailingStore(std::unique_ptr<JobStore> inner) : inner_(std::move(inner)) {}
  void save(const StoredJob& j) override {
    if (failing) throw std::runtime_error("database or disk is full");
    inner_->save(j);
  }
  std::vector<StoredJob> load_all() override { return inner_->load_all(); }
  std::optional<std::string> load_checkpoint(const std::string& id) override { return inner_->load_checkpoint(id); }
  bool remove(const std::string& id) override { return inner_->remove(id); }
  uint64_t next_epoch() override { return inner_->next_epoch(); }
  bool probe() override {
    probes++;
    if (failing) throw std::runtime_error("database or disk is full");
    return inner_->probe();
  }
  std::atomic<bool> failing{false};
  std::atomic<int> probes{0};

 private:
  std::unique_ptr<JobStore> inner_;
};

std::string stored_state(JobStore& s, const std::string& id) {
  for (const StoredJob& j : s.load_all()) {
    if (j.id == id) return j.state;
  }
  return "<missing>";
}

TEST(StoreFailure, NothingIsAcknowledgedThatIsNotStored) {
  auto owned = std::make_unique<FailingStore>(make_memory_store());
  FailingStore* store = owned.get();
  Harness h(test_manager_config(), std::move(owned));

  // A job submitted while the store works, running when the store starts failing.
  const std::string running = h.submit(fake_spec(2'000'000, 20));
  ASSERT_TRUE(h.wait_state(running, "running"));
  store->failing = true;

  // Submissions are refused with 503 naming the cause; none is kept.
  for (int i = 0; i < 5; ++i) {
    const HttpResponse r = h.call("POST", "/v1/jobs", fake_spec(1000).dump());
    EXPECT_EQ(r.status, 503) << r.body;
    EXPECT_NE(r.body.find("disk is full"), std::string::npos) << r.body;
    EXPECT_EQ(r.header("content-type"), "application/problem+json");
  }
  EXPECT_EQ(h.call_json("GET", "/v1/jobs")["jobs"].size(), 1u);
  // Not ready, and the failures are counted.
  ASSERT_TRUE(wait_until([&] { return h.call("GET", "/readyz").status == 503; }, 10));
  EXPECT_NE(h.call("GET", "/readyz").body.find("disk is full"), std::string::npos);
  const std::string metrics = h.call("GET", "/metrics").body;
  EXPECT_NE(metrics.find("tally_store_failures_total "), std::string::npos) << metrics;
  EXPECT_EQ(metrics.find("tally_store_failures_total 0\n"), std::string::npos) << metrics;

  // The running job finishes while nothing can be stored...
  ASSERT_TRUE(h.wait_state(running, "succeeded", 60));
  EXPECT_NE(stored_state(*store, running), "succeeded");
  // ...and once the store works again, its final state is retried and stored.
  store->failing = false;
  ASSERT_TRUE(wait_until([&] { return stored_state(*store, running) == "succeeded"; }, 10))
      << stored_state(*store, running);
  ASSERT_TRUE(wait_until([&] { return h.call("GET", "/readyz").status == 200; }, 10));
  const std::string id = h.submit(fake_spec(1000));
  EXPECT_EQ(stored_state(*store, id).empty(), false);
  EXPECT_NE(stored_state(*store, id), "<missing>");
}

// Issue 27 N9: once a full disk was freed, /readyz stayed 503 until some submit
// succeeded, and a load balancer that sees 503 sends none. A refused submit leaves
// nothing to retry, so the recorder probes the store itself (a small write, off the
// request threads, once a second) while it fails: readiness comes back on its own.
TEST(StoreFailure, ReadinessRecoversWithoutASubmit) {
  auto owned = std::make_unique<FailingStore>(make_memory_store());
  FailingStore* store = owned.get();
  Harness h(test_manager_config(), std::move(owned));
  ASSERT_EQ(h.call("GET", "/readyz").status, 200);
  store->failing = true;
  const HttpResponse refused = h.call("POST", "/v1/jobs", fake_spec(1000).dump());
  ASSERT_EQ(refused.status, 503) << refused.body;
  EXPECT_EQ(h.call("GET", "/readyz").status, 503);
  // While the disk is full the probes fail and readiness stays 503, naming the cause.
  ASSERT_TRUE(wait_until([&] { return store->probes.load() >= 2; }, 10)) << "probes: " << store->probes.load();
  const HttpResponse still = h.call("GET", "/readyz");
  EXPECT_EQ(still.status, 503);
  EXPECT_NE(still.body.find("disk is full"), std::string::npos) << still.body;
  // Space is freed: /readyz is 200 again within a few probe intervals, with no submit.
  store->failing = false;
  EXPECT_TRUE(wait_until([&] { return h.call("GET", "/readyz").status == 200; }, 5)) << h.call("GET", "/readyz").body;
  EXPECT_EQ(h.call_json("GET", "/v1/jobs")["jobs"].size(), 0u) << "recovered without any job being submitted";
  EXPECT_EQ(h.call("POST", "/v1/jobs", fake_spec(1000).dump()).status, 202);
}

// The port used to open only after recovery, so /readyz never said 503. Now the
// server listens first: until the jobs are recovered /readyz is 503 and the job
// routes answer 503 (a partial job list would look like lost jobs).
bool finished_row(const StoredJob& j) { return j.state == "succeeded"; }

// Nothing reads as finished before it is stored. A job used to read as finished before
// its final save (the pass callback saved it after publishing the end): a DELETE in that
// window removed the row and the save then wrote it back, and a crash in it lost a
// result a client had already read. Now the ending is stored first, on the recorder's
// finisher thread, and published after. Here the final save is held at a gate: the job
// reads as running, a DELETE (a cancel, for a running job) is refused with 409, nothing
// is stored as finished; once the gate opens the job reads succeeded, its row says so,
// and DELETE removes the row for good.
TEST(Delete, AJobReadsFinishedOnlyOnceItsFinalSaveIsStored) {
  auto owned = std::make_unique<GatedStore>(make_memory_store(), finished_row);
  GatedStore* store = owned.get();
  Harness h(test_manager_config(), std::move(owned));
  struct OpenAtExit {  // a failed assertion must not leave the finisher held at the gate
    GatedStore* s;
    ~OpenAtExit() { s->open(); }
  } open_at_exit{store};
  const std::string id = h.submit(fake_spec(20000));
  ASSERT_TRUE(store->wait_until_a_save_is_held(30));
  std::this_thread::sleep_for(std::chrono::milliseconds(100));  // time to publish, were it not held
  EXPECT_EQ(h.call_json("GET", "/v1/jobs/" + id).at("state"), "running");
  const HttpResponse del = h.call("DELETE", "/v1/jobs/" + id);
  EXPECT_EQ(del.status, 409);
  EXPECT_NE(del.body.find("being stored"), std::string::npos) << del.body;
  EXPECT_NE(stored_state(*store, id), "succeeded");
  store->open();
  ASSERT_TRUE(h.wait_state(id, "succeeded"));
  EXPECT_EQ(stored_state(*store, id), "succeeded");  // stored before it read so
  EXPECT_EQ(h.call("DELETE", "/v1/jobs/" + id).status, 204);
  EXPECT_EQ(stored_state(*store, id), "<missing>");
  EXPECT_FALSE(store->load_checkpoint(id).has_value());
  EXPECT_EQ(h.call("GET", "/v1/jobs/" + id).status, 404);
}

// A checkpoint used to be encoded and written on the thread that committed the pass:
// an image's (7 MB for 128x96 with replicates) took ~260 ms, every worker waiting, and
// the cluster's coordinator paid it ~5 times per image job. A running job's checkpoint
// is now written on the recorder's thread: here one is held at a gate, and the job's
// passes go on past it (the held one, streamed from the live state, is abandoned once
// the next pass commits); the held (older) row never overwrites the final one.
TEST(Checkpoint, AHeldCheckpointSaveDoesNotHoldUpThePasses) {
  auto owned = std::make_unique<GatedStore>(make_memory_store(), [](const StoredJob& j) {
    return j.state == "running" && (j.checkpoint.has_value() || j.checkpoint_stream);
  });
  GatedStore* store = owned.get();
  Harness h(test_manager_config(), std::move(owned));  // a checkpoint at every pass
  struct OpenAtExit {
    GatedStore* s;
    ~OpenAtExit() { s->open(); }
  } open_at_exit{store};
  const std::string id = h.submit(fake_spec(2'000'000, 20));  // ~34 passes
  ASSERT_TRUE(store->wait_until_a_save_is_held(30));
  auto passes = [&] { return h.call_json("GET", "/v1/jobs/" + id).value("passes", uint64_t{0}); };
  const uint64_t held_at = passes();
  EXPECT_TRUE(wait_until([&] { return passes() >= held_at + 3; }, 30)) << "passes stalled at " << passes();
  store->open();
  ASSERT_TRUE(h.wait_state(id, "succeeded", 60));
  EXPECT_TRUE(wait_until([&] { return stored_state(*store, id) == "succeeded"; }, 10)) << stored_state(*store, id);
  EXPECT_EQ(stored_state(*store, id), "succeeded");
}

// Status and list documents are built from a snapshot for the views, which copies no
// runner (a running 512x512 image's state is ~150 MB, copied on an I/O thread at every
// pass: status GETs took 0.5 s each, and /readyz waited behind them). They must read
// exactly as the documents built from the runner, while the job runs and once its last
// pass is merged (its final save held at the gate).
TEST(Snapshot, DocumentsCopyNoRunnerAndReadAsFromTheRunner) {
  auto owned = std::make_unique<GatedStore>(make_memory_store(), [](const StoredJob& j) {
    return j.state == "succeeded";
  });
  GatedStore* store = owned.get();
  Harness h(test_manager_config(), std::move(owned));
  struct OpenAtExit {
    GatedStore* s;
    ~OpenAtExit() { s->open(); }
  } open_at_exit{store};
  const std::string id = h.submit(fake_spec(1'000'000, 20, 3, true));  // an image, ~20 passes
  const json links = json::object();
  // Both snapshots at the same version (the job moves on between them: try again).
  auto compare = [&](JobStatus want) {
    for (int i = 0; i < 2000; ++i) {
      const JobSnapshot v = h.manager->snapshot(id);
      const JobSnapshot s = h.manager->snapshot(id, JobManager::SnapshotOf::state);
      // A pass being published (committed, its views not built yet) shows the last
      // pass's views: compare once they are built.
      if (v.version != s.version || v.status != want || !v.facts || !s.runner ||
          s.runner->state().passes == 0 || v.facts->passes != s.runner->state().passes) {
        std::this_thread::sleep_for(std::chrono::milliseconds(1));
        continue;
      }
      EXPECT_EQ(v.runner, nullptr);
      EXPECT_NE(s.runner, nullptr);
      EXPECT_EQ(status_json(v, 1e9, links), status_json(s, 1e9, links));
      EXPECT_EQ(summary_json(v), summary_json(s));
      return true;
    }
    return false;
  };
  int running = 0;
  for (int k = 0; k < 3; ++k) running += compare(JobStatus::running) ? 1 : 0;
  EXPECT_GE(running, 1) << "never saw the job running after a pass";
  // Its final save held at the gate: the job still reads as running (it reads as
  // finished once stored), with its last pass's figures, the same from either snapshot.
  ASSERT_TRUE(store->wait_until_a_save_is_held(60));
  EXPECT_TRUE(compare(JobStatus::running));
  store->open();
  ASSERT_TRUE(h.wait_state(id, "succeeded", 60));
  EXPECT_EQ(stored_state(*store, id), "succeeded");
}

TEST(Readiness, JobRoutesWaitForRecovery) {
  Harness h;
  h.handler->set_ready(false);
  EXPECT_EQ(h.call("GET", "/livez").status, 200);
  EXPECT_EQ(h.call("GET", "/readyz").status, 503);
  EXPECT_EQ(h.call("GET", "/metrics").status, 200);
  const HttpResponse list = h.call("GET", "/v1/jobs");
  EXPECT_EQ(list.status, 503);
  EXPECT_EQ(list.header("retry-after"), "1");
  EXPECT_EQ(h.call("POST", "/v1/jobs", fake_spec(10).dump()).status, 503);
  h.handler->set_ready(true);
  EXPECT_EQ(h.call("GET", "/readyz").status, 200);
  EXPECT_EQ(h.call("GET", "/v1/jobs").status, 200);
}

// Wraps a store; every save of a running job's checkpoint starts `delay` late (a store
// slower than the job's passes), and counts which of them landed and which were
// abandoned (JobRecorder::store: the state moved on while it was being written).
class SlowCheckpointStore final : public JobStore {
 public:
  SlowCheckpointStore(std::unique_ptr<JobStore> inner, std::chrono::milliseconds delay)
      : inner_(std::move(inner)), delay_(delay) {}
  void save(const StoredJob& j) override {
    const bool periodic = j.state == "running" && (j.checkpoint.has_value() || j.checkpoint_stream);
    if (!periodic) return inner_->save(j);
    std::this_thread::sleep_for(delay_);
    try {
      inner_->save(j);
    } catch (...) {
      ++abandoned;
      if (landed == 0) ++abandoned_before_first;
      throw;
    }
    ++landed;
  }
  std::vector<StoredJob> load_all() override { return inner_->load_all(); }
  std::optional<std::string> load_checkpoint(const std::string& id) override { return inner_->load_checkpoint(id); }
  bool remove(const std::string& id) override { return inner_->remove(id); }
  uint64_t next_epoch() override { return inner_->next_epoch(); }
  std::atomic<int> landed{0}, abandoned{0}, abandoned_before_first{0};

 private:
  std::unique_ptr<JobStore> inner_;
  std::chrono::milliseconds delay_;
};

// A job's periodic checkpoints must land however slow the store is against its passes.
// Streamed from the live state, a checkpoint is abandoned when a pass commits while it
// is written: with a store 50 ms late and passes of a few ms, every checkpoint of such a
// job was abandoned, and a kill -9 lost all its work. Now a small state is copied at the
// pass boundary (nothing to abandon), and a big one that was abandoned once holds the
// next commit until it is stored.
TEST(Checkpoint, SmallStatesCheckpointsLandThoughTheStoreIsSlowerThanAPass) {
  auto owned = std::make_unique<SlowCheckpointStore>(make_memory_store(), std::chrono::milliseconds(50));
  SlowCheckpointStore* store = owned.get();
  Harness h(test_manager_config(), std::move(owned));  // a checkpoint at every pass
  const std::string id = h.submit(fake_spec(4'000'000'000, 20));
  EXPECT_TRUE(wait_until([&] { return store->landed + store->abandoned >= 4; }, 30));
  const json mid = h.call_json("GET", "/v1/jobs/" + id);
  h.call("DELETE", "/v1/jobs/" + id);
  ASSERT_TRUE(h.wait_state(id, "cancelled"));
  EXPECT_EQ(mid.at("state"), "running");
  EXPECT_GE(store->landed, 4);
  EXPECT_EQ(store->abandoned, 0);
}

TEST(Checkpoint, AfterAnAbandonedCheckpointTheNextOneLands) {
  auto owned = std::make_unique<SlowCheckpointStore>(make_memory_store(), std::chrono::milliseconds(50));
  SlowCheckpointStore* store = owned.get();
  ManagerConfig mc = test_manager_config();
  mc.checkpoint_copy_bytes = 0;  // every state streams from the live one, as an image's does
  mc.stream_passes = false;      // whole passes merge (as behind a cluster): a commit can abandon one
  Harness h(mc, std::move(owned));
  const std::string id = h.submit(fake_spec(4'000'000'000, 20));
  EXPECT_TRUE(wait_until([&] { return store->landed >= 3; }, 30))
      << store->landed << " landed, " << store->abandoned << " abandoned";
  h.call("DELETE", "/v1/jobs/" + id);
  ASSERT_TRUE(h.wait_state(id, "cancelled"));
  EXPECT_EQ(store->abandoned_before_first, 1) << "the first is abandoned (the passes are faster), the next lands";
  EXPECT_LE(store->abandoned, store->landed + 1) << "never two abandoned in a row";
}

// A streamed job (its state streams to the store, and so do its passes: the default for
// an image) merges each result group as it comes, so a checkpoint written from the live
// state would find it changed at once. Its merges wait for the checkpoint instead:
// none is abandoned, every one lands, and the work goes on.
TEST(Checkpoint, StreamedPassesWaitForTheCheckpointNoneAbandoned) {
  auto owned = std::make_unique<SlowCheckpointStore>(make_memory_store(), std::chrono::milliseconds(50));
  SlowCheckpointStore* store = owned.get();
  ManagerConfig mc = test_manager_config();
  mc.checkpoint_copy_bytes = 0;  // every state streams from the live one: its passes stream too
  Harness h(mc, std::move(owned));
  const std::string id = h.submit(fake_spec(4'000'000'000, 20, 1, true));
  EXPECT_TRUE(wait_until([&] { return store->landed >= 4; }, 30))
      << store->landed << " landed, " << store->abandoned << " abandoned";
  const uint64_t streamed = h.manager->stats().groups_streamed;
  h.call("DELETE", "/v1/jobs/" + id);
  ASSERT_TRUE(h.wait_state(id, "cancelled"));
  EXPECT_GT(streamed, 0u) << "the passes were not streamed";
  EXPECT_EQ(store->abandoned, 0);
}

}  // namespace
}  // namespace tally::test
