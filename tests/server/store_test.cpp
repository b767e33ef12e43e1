// The SQLite job store and recovery: round trips, checkpoints kept across
// state-only saves, epochs, and a restarted manager resuming bit-identically or
// reporting a corrupt checkpoint.
#include <gtest/gtest.h>
#include <SQLiteCpp/SQLiteCpp.h>

#include <filesystem>
#include <future>
#include <map>
#include <thread>

#include <fmt/format.h>

#include "server/jobs/sqlite_salvage.hpp"
#include "server_test_support.hpp"
#include "tests/support/sqlite_damage.hpp"

namespace tally::test {
namespace {

using nlohmann::json;

struct TempDir {
  TempDir() {
    path = std::filesystem::temp_directory_path() /
           ("tally_store_test_" + std::to_string(::getpid()) + "_" + std::to_string(counter++));
    std::filesystem::remove_all(path);
    std::filesystem::create_directories(path);
  }
  ~TempDir() { std::filesystem::remove_all(path); }
  std::filesystem::path path;
  static inline int counter = 0;
};

TEST(JobStore, SqliteRoundTripKeepsCheckpointOnStateOnlySaves) {
  TempDir dir;
  {
    auto store = open_sqlite_store(dir.path.string());
    EXPECT_EQ(store->next_epoch(), 1u);
    StoredJob j;
    j.id = "abc";
    j.seq = 3;
    j.spec = "{\"kind\":\"fake\"}";
    j.priority = 2;
    j.state = "running";
    j.stop_rule = "{\"max_samples\":5}";
    j.checkpoint = std::string("\0\1\2binary", 9);
    j.created_at = 1.5;
    store->save(j);
    j.checkpoint.reset();
    j.state = "succeeded";
    j.result = "{\"x\":1}";
    j.finished_at = 2.5;
    store->save(j);
  }
  auto store = open_sqlite_store(dir.path.string());
  EXPECT_EQ(store->next_epoch(), 2u);
  const auto rows = store->load_all();
  ASSERT_EQ(rows.size(), 1u);
  EXPECT_EQ(rows[0].id, "abc");
  EXPECT_EQ(rows[0].seq, 3);
  EXPECT_EQ(rows[0].priority, 2);
  EXPECT_EQ(rows[0].state, "succeeded");
  EXPECT_EQ(rows[0].result, "{\"x\":1}");
  // A finished job's checkpoint stays on disk until asked for (issue 13).
  EXPECT_FALSE(rows[0].checkpoint);
  const auto cp = store->load_checkpoint("abc");
  ASSERT_TRUE(cp);
  EXPECT_EQ(*cp, std::string("\0\1\2binary", 9));
  EXPECT_FALSE(store->load_checkpoint("nope"));
  EXPECT_TRUE(store->remove("abc"));
  EXPECT_FALSE(store->remove("abc"));
  EXPECT_TRUE(store->load_all().empty());
  EXPECT_FALSE(store->load_checkpoint("abc"));
  EXPECT_DOUBLE_EQ(rows[0].created_at, 1.5);
  EXPECT_DOUBLE_EQ(rows[0].finished_at, 2.5);
}

// PATCH /v1/jobs/{id} changes a job's priority after its row exists: a later save stores
// the new value (the upsert kept the first one).
TEST(JobStore, SqliteSaveUpdatesThePriority) {
  TempDir dir;
  auto store = open_sqlite_store(dir.path.string());
  StoredJob j;
  j.id = "abc";
  j.state = "queued";  // priority 0
  store->save(j);
  j.priority = -3;
  store->save(j);
  const auto rows = store->load_all();
  ASSERT_EQ(rows.size(), 1u);
  EXPECT_EQ(rows[0].priority, -3);
}

// A data dir SQLite cannot write (read-only, or tally.db not a file) failed with
// "unable to open database file" and no path. (As root a chmod does not stop us, so
// the database path is made a directory.)
TEST(JobStore, UnopenableDatabaseErrorNamesThePath) {
  TempDir dir;
  std::filesystem::create_directories(dir.path / "tally.db");
  try {
    open_sqlite_store(dir.path.string());
    FAIL() << "opened a database that is a directory";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find((dir.path / "tally.db").string()), std::string::npos) << e.what();
  }
}

// A finished job as the recorder stores it: its RunFacts in `facts`, its checkpoint
// kept on disk.
StoredJob finished_job(int i) {
  StoredJob j;
  j.id = fmt::format("job{:03}", i);
  j.seq = i;
  j.spec = fmt::format("{{\"kind\":\"fake\",\"pad\":\"{}\"}}", std::string(300, 'p'));
  j.priority = i % 3;
  j.state = "succeeded";
  j.stop_rule = "{\"max_samples\":5}";
  j.result = fmt::format("{{\"x\":{}}}", i);
  j.checkpoint = std::string("\0cp", 3) + std::to_string(i);
  j.created_at = 1.0 + i;
  j.started_at = 2.0 + i;
  j.finished_at = 3.0 + i;
  j.owner = i % 2 ? "alice" : "";
  j.facts = fmt::format("{{\"samples\":{},\"stop_reason\":\"max_samples\"}}", 1000 + i);
  return j;
}

void expect_same_row(const StoredJob& got, const StoredJob& want) {
  EXPECT_EQ(got.id, want.id);
  EXPECT_EQ(got.seq, want.seq);
  EXPECT_EQ(got.spec, want.spec);
  EXPECT_EQ(got.priority, want.priority);
  EXPECT_EQ(got.state, want.state);
  EXPECT_EQ(got.stop_rule, want.stop_rule);
  EXPECT_EQ(got.result, want.result);
  EXPECT_EQ(got.owner, want.owner);
  EXPECT_EQ(got.facts, want.facts) << got.id;
  EXPECT_EQ(got.created_at, want.created_at);
  EXPECT_EQ(got.started_at, want.started_at);
  EXPECT_EQ(got.finished_at, want.finished_at);
}

// The salvage of a damaged tally.db had its own row reader, which missed the facts
// column: a salvaged finished job came back without its RunFacts. Salvage reads
// every column the store writes (here from an undamaged file, so every row).
TEST(JobStore, SalvageKeepsAFinishedJobsFacts) {
  TempDir dir;
  std::vector<StoredJob> saved;
  {
    auto store = open_sqlite_store(dir.path.string());
    for (int i = 1; i <= 3; ++i) {
      saved.push_back(finished_job(i));
      store->save(saved.back());
    }
  }
  const SalvageResult r = quarantine_and_salvage((dir.path / "tally.db").string());
  EXPECT_TRUE(r.lost.empty());
  EXPECT_TRUE(r.partial.empty());
  ASSERT_EQ(r.jobs.size(), saved.size());
  for (size_t i = 0; i < saved.size(); ++i) {
    expect_same_row(r.jobs[i], saved[i]);
    EXPECT_EQ(r.jobs[i].checkpoint, saved[i].checkpoint);
  }
}

// The whole path: a damaged leaf page, the store reopened (quarantine, salvage, the
// rows saved into a fresh file); every finished job it kept has its facts.
TEST(JobStore, DamagedStoreKeepsTheSalvagedJobsFacts) {
  TempDir dir;
  const std::filesystem::path db = dir.path / "tally.db";
  constexpr int kJobs = 60;
  std::map<std::string, StoredJob> saved;
  {
    auto store = open_sqlite_store(dir.path.string());
    for (int i = 1; i <= kJobs; ++i) {
      StoredJob j = finished_job(i);
      store->save(j);
      saved[j.id] = j;
    }
  }
  const DamagedPage damaged = damage_middle_jobs_leaf(db);
  ASSERT_GE(damaged.leaves, 3u) << "the jobs table should span several pages";
  ASSERT_TRUE(damaged.written);
  auto store = open_sqlite_store(dir.path.string());
  ASSERT_TRUE(store->damage()) << "the damaged page went unnoticed";
  const auto rows = store->load_all();
  EXPECT_GE(rows.size(), static_cast<size_t>(kJobs) / 2);
  EXPECT_LT(rows.size(), static_cast<size_t>(kJobs));
  for (const StoredJob& row : rows) {
    ASSERT_TRUE(saved.count(row.id)) << row.id;
    expect_same_row(row, saved[row.id]);
  }
}

// A file from before the owner and facts columns whose migration never ran (a
// damaged one): salvage reads those columns as "".
TEST(JobStore, SalvageReadsAFileFromBeforeOwnerAndFacts) {
  TempDir dir;
  const std::string path = (dir.path / "tally.db").string();
  {
    SQLite::Database d(path, SQLite::OPEN_READWRITE | SQLite::OPEN_CREATE);
    d.exec("CREATE TABLE jobs (id TEXT PRIMARY KEY, seq INTEGER NOT NULL, spec TEXT NOT NULL,"
           " priority INTEGER NOT NULL, state TEXT NOT NULL, stop_rule TEXT NOT NULL, error TEXT NOT NULL DEFAULT '',"
           " result TEXT NOT NULL DEFAULT '', checkpoint BLOB, created_at REAL NOT NULL, started_at REAL NOT NULL,"
           " finished_at REAL NOT NULL, updated_at REAL NOT NULL DEFAULT 0)");
    d.exec("INSERT INTO jobs (id, seq, spec, priority, state, stop_rule, result, checkpoint, created_at, started_at,"
           " finished_at) VALUES ('old', 4, '{}', 1, 'succeeded', '{}', '{\"x\":2}', x'0001', 1.0, 2.0, 3.0)");
  }
  const SalvageResult r = quarantine_and_salvage(path);
  EXPECT_TRUE(r.lost.empty());
  ASSERT_EQ(r.jobs.size(), 1u);
  EXPECT_EQ(r.jobs[0].id, "old");
  EXPECT_EQ(r.jobs[0].seq, 4);
  EXPECT_EQ(r.jobs[0].result, "{\"x\":2}");
  EXPECT_EQ(r.jobs[0].owner, "");
  EXPECT_EQ(r.jobs[0].facts, "");
  EXPECT_EQ(r.jobs[0].checkpoint, std::string("\0\1", 2));
}

TEST(JobStore, MemoryStoreBehavesLikeSqlite) {
  auto store = make_memory_store();
  StoredJob j;
  j.id = "b";
  j.seq = 2;
  j.checkpoint = "cp";
  store->save(j);
  j.checkpoint.reset();
  j.state = "failed";
  store->save(j);
  StoredJob a;
  a.id = "a";
  a.seq = 1;
  store->save(a);
  const auto rows = store->load_all();
  ASSERT_EQ(rows.size(), 2u);
  EXPECT_EQ(rows[0].id, "a");
  EXPECT_EQ(rows[1].state, "failed");
  EXPECT_FALSE(rows[1].checkpoint);  // finished: on request only
  EXPECT_EQ(store->load_checkpoint("b").value_or(""), "cp");
  EXPECT_TRUE(store->remove("b"));
  EXPECT_EQ(store->load_all().size(), 1u);
}

// `size` bytes whose value drifts with the position ((i * mul) >> shift), so a piece
// read back in the wrong place or order differs.
std::string patterned_bytes(size_t size, size_t mul, int shift) {
  std::string out(size, '\0');
  for (size_t i = 0; i < size; ++i) out[i] = static_cast<char>((i * mul) >> shift);
  return out;
}

// The two stores every store test below must pass: SQLite in `dir`, and memory.
std::vector<std::unique_ptr<JobStore>> both_stores(const TempDir& dir) {
  std::vector<std::unique_ptr<JobStore>> stores;
  stores.push_back(open_sqlite_store(dir.path.string()));
  stores.push_back(make_memory_store());
  return stores;
}

// A checkpoint larger than one piece (SQLite refuses a blob over 1e9 bytes; a 1080p
// image's checkpoint is 1.2 GB, and its final save failed with "string or blob too
// big") is streamed in pieces and read back whole, by both stores; a new one replaces
// every piece of the old; removing the job removes its pieces.
TEST(JobStore, CheckpointOverOnePieceStreamsInAndReadsBack) {
  const size_t size = 2 * kCheckpointPieceBytes + 5;
  const std::string expected = patterned_bytes(size, 131, 3);
  TempDir dir;
  std::vector<std::unique_ptr<JobStore>> stores = both_stores(dir);
  for (auto& store : stores) {
    StoredJob j;
    j.id = "big";
    j.seq = 1;
    j.state = "running";
    size_t calls = 0;
    j.checkpoint_stream = [&](const CheckpointSink& sink) {
      ++calls;
      for (size_t at = 0; at < size; at += kCheckpointPieceBytes) {
        sink(std::string_view(expected).substr(at, kCheckpointPieceBytes));
      }
      return static_cast<uint64_t>(size);
    };
    store->save(j);
    EXPECT_EQ(calls, 1u);
    EXPECT_EQ(store->load_checkpoint("big"), expected);
    auto rows = store->load_all();
    ASSERT_EQ(rows.size(), 1u);
    EXPECT_EQ(rows[0].checkpoint, expected);
    EXPECT_GE(rows[0].stored_bytes, size);
    j.checkpoint_stream = nullptr;
    j.checkpoint = "small";
    store->save(j);
    EXPECT_EQ(store->load_checkpoint("big"), "small");
    EXPECT_LT(store->load_all().at(0).stored_bytes, 1000u);
    j.checkpoint.reset();  // a state-only save keeps it
    j.state = "succeeded";
    store->save(j);
    EXPECT_EQ(store->load_checkpoint("big"), "small");
    EXPECT_TRUE(store->remove("big"));
    EXPECT_FALSE(store->load_checkpoint("big"));
  }
  stores.clear();
  SQLite::Database d((dir.path / "tally.db").string(), SQLite::OPEN_READONLY);
  EXPECT_EQ(d.execAndGet("SELECT count(*) FROM checkpoint_pieces").getInt64(), 0);
}

// A checkpoint's encoding (JobRecorder streams it from the job's state, piece by piece,
// waiting for the job's passes) used to run under the store's lock: every other save
// waited for it, so a submit was acknowledged seconds late while an image job
// checkpointed. Now both stores encode a streamed checkpoint before they lock (the SQLite
// one into an unlinked spool file in its directory): here one stream is held half-way,
// and another job's save lands meanwhile; then the held one lands whole, and no spool
// file is left behind.
TEST(JobStore, OtherSavesDoNotWaitForAStreamedCheckpointsEncoding) {
  const size_t size = kCheckpointPieceBytes + 7;
  const std::string expected = patterned_bytes(size, 37, 2);
  TempDir dir;
  std::vector<std::unique_ptr<JobStore>> stores = both_stores(dir);
  for (auto& store : stores) {
    std::promise<void> half_way, go_on;
    std::shared_future<void> go = go_on.get_future().share();
    StoredJob big;
    big.id = "big";
    big.seq = 1;
    big.state = "running";
    big.checkpoint_stream = [&](const CheckpointSink& sink) {
      sink(std::string_view(expected).substr(0, kCheckpointPieceBytes));
      half_way.set_value();
      go.wait();
      sink(std::string_view(expected).substr(kCheckpointPieceBytes));
      return static_cast<uint64_t>(size);
    };
    std::thread saver([&] { store->save(big); });
    half_way.get_future().wait();
    StoredJob other;
    other.id = "other";
    other.seq = 2;
    other.state = "queued";
    auto landed = std::async(std::launch::async, [&] { store->save(other); });
    const bool in_time = landed.wait_for(std::chrono::seconds(20)) == std::future_status::ready;
    EXPECT_TRUE(in_time) << "another job's save waited for the held encoding";
    go_on.set_value();
    saver.join();
    landed.get();
    EXPECT_EQ(store->load_checkpoint("big"), expected);
    ASSERT_EQ(store->load_all().size(), 2u);
  }
  stores.clear();
  for (const auto& e : std::filesystem::directory_iterator(dir.path)) {
    EXPECT_EQ(e.path().filename().string().rfind(".checkpoint-spool", 0), std::string::npos) << e.path();
  }
}

// A file written before checkpoints came in pieces keeps its checkpoint in the jobs
// table: it still reads (load_checkpoint, load_all), and the next checkpoint saved
// replaces it (in pieces, which a salvage reads as well).
TEST(JobStore, CheckpointInTheOldColumnStillReads) {
  TempDir dir;
  {
    auto store = open_sqlite_store(dir.path.string());
    StoredJob j;
    j.id = "old";
    j.seq = 1;
    j.state = "running";
    store->save(j);
  }
  {
    SQLite::Database d((dir.path / "tally.db").string(), SQLite::OPEN_READWRITE);
    d.exec("UPDATE jobs SET checkpoint = x'0001ff' WHERE id = 'old'");
    d.exec("DROP TABLE checkpoint_pieces");
  }
  auto store = open_sqlite_store(dir.path.string());
  EXPECT_EQ(store->load_checkpoint("old"), std::string("\0\1\xff", 3));
  EXPECT_EQ(store->load_all().at(0).checkpoint, std::string("\0\1\xff", 3));
  StoredJob j = store->load_all().at(0);
  j.checkpoint = "new";
  store->save(j);
  EXPECT_EQ(store->load_checkpoint("old"), "new");
  store.reset();
  {
    SQLite::Database d((dir.path / "tally.db").string(), SQLite::OPEN_READONLY);
    EXPECT_TRUE(d.execAndGet("SELECT checkpoint FROM jobs WHERE id = 'old'").isNull());
  }
  // A salvage reads the pieces too.
  const SalvageResult r = quarantine_and_salvage((dir.path / "tally.db").string());
  ASSERT_EQ(r.jobs.size(), 1u);
  EXPECT_EQ(r.jobs[0].checkpoint, "new");
}

// Runs a job to the end in one go and returns its bits.
std::string uninterrupted_bits(const json& spec) {
  Harness h;
  const std::string id = h.submit(spec);
  EXPECT_TRUE(h.wait_state(id, "succeeded", 60));
  return h.call_json("GET", "/v1/jobs/" + id).at("bits").dump();
}

TEST(Recovery, ResumedJobEndsBitIdentical) {
  const json spec = fake_spec(600000, 20, 5);
  const std::string expected = uninterrupted_bits(spec);
  TempDir dir;
  std::string id;
  for (int stop_after_passes : {1, 3, 5}) {
    Harness h(test_manager_config(2), open_sqlite_store(dir.path.string()));
    if (id.empty()) id = h.submit(spec);
    const uint64_t start = h.call_json("GET", "/v1/jobs/" + id).value("passes", uint64_t{0});
    ASSERT_TRUE(wait_until([&] {
      const json s = h.call_json("GET", "/v1/jobs/" + id);
      return s.value("passes", uint64_t{0}) >= start + 1 || s.at("state") == "succeeded";
    }));
    (void)stop_after_passes;
    h.manager->shutdown();  // like SIGTERM: partial pass dropped, last boundary stored
  }
  Harness h(test_manager_config(3), open_sqlite_store(dir.path.string()));
  ASSERT_TRUE(h.wait_state(id, "succeeded", 60));
  EXPECT_EQ(h.call_json("GET", "/v1/jobs/" + id).at("bits").dump(), expected);
}

TEST(Recovery, FinishedJobsAreServedAndExtendable) {
  TempDir dir;
  std::string id, body;
  {
    Harness h(test_manager_config(), open_sqlite_store(dir.path.string()));
    id = h.submit(fake_spec(20000));
    ASSERT_TRUE(h.wait_state(id, "succeeded"));
    body = h.call_json("GET", "/v1/jobs/" + id).at("bits").dump();
  }
  Harness h(test_manager_config(), open_sqlite_store(dir.path.string()));
  const json s = h.call_json("GET", "/v1/jobs/" + id);
  EXPECT_EQ(s.at("state"), "succeeded");
  EXPECT_EQ(s.at("bits").dump(), body);
  EXPECT_EQ(s.at("samples"), 20000);
  ASSERT_EQ(h.call("POST", "/v1/jobs/" + id + "/extend", "{\"max_samples\": 40000}").status, 202);
  ASSERT_TRUE(h.wait_state(id, "succeeded"));
  EXPECT_EQ(h.call_json("GET", "/v1/jobs/" + id).at("samples"), 40000);
}

// A deterministic estimator (quadrature) stops on "one pass decides": min_samples 1,
// which the store keeps with the rule. The recovery read stored rules with the spec
// reader (min_samples at least 2), refused that one and fell back to the spec's rule:
// after a restart an extended quadrature job read max_samples 1 again, and one still
// running when the server was killed finished at once, its acknowledged extend lost
// (found by scripts/soak.py: "stored stop rule is unreadable" at every restart).
TEST(Recovery, ExtendedDeterministicJobKeepsItsRuleAcrossARestart) {
  TempDir dir;
  const json spec = {{"kind", "integrate"},
                     {"seed", 3},
                     {"integrand", {{"expression", "x0 * x1 + sin(x0)"}}},
                     {"domain", {{"type", "box"}, {"lower", {0, 0}}, {"upper", {1, 1}}}},
                     {"estimator", {{"type", "quadrature"}, {"points_per_dim", 9}}},
                     {"stop", {{"max_samples", 1}}}};
  std::string id;
  json before;
  {
    Harness h(test_manager_config(), open_sqlite_store(dir.path.string()), {}, compile_any);
    id = h.submit(spec);
    ASSERT_TRUE(h.wait_state(id, "succeeded"));
    ASSERT_EQ(h.call("POST", "/v1/jobs/" + id + "/extend", R"({"max_samples": 5})").status, 202);
    ASSERT_TRUE(h.wait_state(id, "succeeded"));
    before = h.call_json("GET", "/v1/jobs/" + id);
    ASSERT_EQ(before.at("stop_rule"), json::parse(R"({"confidence": 0.95, "max_samples": 5, "min_samples": 1})"));
    ASSERT_EQ(before.at("samples"), 5);
  }
  Harness h(test_manager_config(), open_sqlite_store(dir.path.string()), {}, compile_any);
  const json after = h.call_json("GET", "/v1/jobs/" + id);
  EXPECT_EQ(after.at("stop_rule"), before.at("stop_rule"));
  EXPECT_EQ(after.at("samples"), 5);
  EXPECT_EQ(after.at("bits"), before.at("bits"));
}

// Per-component targets (issue 31) through the handler and the store: a job that
// max_samples stops first reports its unmet component; an extend keeps the targets and
// runs to them; a restart reads them back from the stored rule with the same bits.
// x, x^2, x^3 over [0, 1] on the frozen-grid (uniform) VEGAS kernel, only component
// targets: x needs ~13k samples for 1e-2 relative, x^2 ~85k for 2e-3 absolute, x^3 ~3k
// for 4e-2 relative.
TEST(Recovery, ComponentTargetsKeptAcrossExtendAndRestart) {
  const auto powers_job = [](uint64_t max_samples) {
    return json{{"kind", "integrate"},
                {"seed", 9},
                {"integrand", {{"expressions", {"x0", "x0^2", "x0^3"}}}},
                {"domain", {{"type", "box"}, {"lower", {0.0}}, {"upper", {1.0}}}},
                {"estimator", {{"type", "uniform"}}},
                {"stop",
                 {{"max_samples", max_samples},
                  {"component_targets",
                   {{"abs_error", {nullptr, 2e-3, nullptr}}, {"rel_error", {1e-2, nullptr, 4e-2}}}}}}};
  };
  TempDir dir;
  std::string id;
  json before;
  const json rule = powers_job(1).at("stop").at("component_targets");
  {
    Harness h(test_manager_config(), open_sqlite_store(dir.path.string()), {}, compile_any);
    id = h.submit(powers_job(20000));
    ASSERT_TRUE(h.wait_state(id, "succeeded"));
    const json s = h.call_json("GET", "/v1/jobs/" + id);
    EXPECT_EQ(s.at("stop_reason"), "max_samples") << s.dump();
    EXPECT_EQ(s.at("target_met"), false);
    // 20000 samples: x (~13k) and x^3 (~3k) meet theirs, x^2 (~85k) does not.
    const json& cs = s.at("result").at("components_summary");
    EXPECT_EQ(cs.at("met"), 2) << cs.dump();
    EXPECT_EQ(cs.at("unmet"), json::parse(R"({"count": 1, "first": [1]})")) << cs.dump();
    EXPECT_EQ(cs.at("worst").at("index"), 1);
    EXPECT_EQ(s.at("stop_rule").at("component_targets"), rule) << s.dump();
    ASSERT_EQ(h.call("POST", "/v1/jobs/" + id + "/extend", R"({"max_samples": 4000000})").status, 202);
    ASSERT_TRUE(h.wait_state(id, "succeeded", 60));
    before = h.call_json("GET", "/v1/jobs/" + id);
    EXPECT_EQ(before.at("stop_reason"), "error_target") << before.dump();
    EXPECT_EQ(before.at("target_met"), true);
    EXPECT_EQ(before.at("result").at("components_summary").at("met"), 3);
    EXPECT_FALSE(before.at("result").at("components_summary").contains("unmet"));
    EXPECT_LT(before.at("samples").get<uint64_t>(), 4000000u);
    EXPECT_EQ(before.at("stop_rule").at("component_targets"), rule);
    EXPECT_EQ(before.at("stop_rule").at("max_samples"), 4000000);
  }
  Harness h(test_manager_config(), open_sqlite_store(dir.path.string()), {}, compile_any);
  const json after = h.call_json("GET", "/v1/jobs/" + id);
  EXPECT_EQ(after.at("stop_rule"), before.at("stop_rule"));
  EXPECT_EQ(after.at("samples"), before.at("samples"));
  EXPECT_EQ(after.at("bits"), before.at("bits"));
  EXPECT_EQ(after.at("result").at("components_summary"), before.at("result").at("components_summary"));
}

TEST(Recovery, CorruptCheckpointIsReportedNotReset) {
  TempDir dir;
  std::string id;
  {
    Harness h(test_manager_config(), open_sqlite_store(dir.path.string()));
    id = h.submit(fake_spec(kForever, 50));
    ASSERT_TRUE(wait_until([&] { return h.call_json("GET", "/v1/jobs/" + id).value("passes", 0) >= 2; }));
    h.manager->shutdown();
  }
  {
    SQLite::Database db((dir.path / "tally.db").string(), SQLite::OPEN_READWRITE);
    // Truncate the checkpoint (one piece: a fake job's is small) to half its length.
    ASSERT_EQ(db.execAndGet("SELECT count(*) FROM checkpoint_pieces").getInt64(), 1);
    db.exec("UPDATE checkpoint_pieces SET bytes = substr(bytes, 1, length(bytes) / 2)");
  }
  Harness h(test_manager_config(), open_sqlite_store(dir.path.string()));
  const json s = h.call_json("GET", "/v1/jobs/" + id);
  EXPECT_EQ(s.at("state"), "failed");
  EXPECT_NE(s.at("error_message").get<std::string>().find("checkpoint"), std::string::npos) << s.dump();
  // The failure is stored: it stays failed on the next start too.
  Harness h2(test_manager_config(), open_sqlite_store(dir.path.string()));
  h.manager->shutdown();
  EXPECT_EQ(h2.state(id), "failed");
}

TEST(Recovery, FlippedByteInCheckpointIsReported) {
  TempDir dir;
  std::string id;
  {
    Harness h(test_manager_config(), open_sqlite_store(dir.path.string()));
    id = h.submit(fake_spec(kForever, 50));
    ASSERT_TRUE(wait_until([&] { return h.call_json("GET", "/v1/jobs/" + id).value("passes", 0) >= 2; }));
    h.manager->shutdown();
  }
  {
    SQLite::Database db((dir.path / "tally.db").string(), SQLite::OPEN_READWRITE);
    SQLite::Statement q(db, "SELECT bytes FROM checkpoint_pieces WHERE n = 0");
    ASSERT_TRUE(q.executeStep());
    const SQLite::Column c = q.getColumn(0);
    std::string blob(static_cast<const char*>(c.getBlob()), static_cast<size_t>(c.getBytes()));
    q.reset();
    ASSERT_GT(blob.size(), 100u);
    blob[blob.size() / 2] = static_cast<char>(blob[blob.size() / 2] ^ 0x40);
    SQLite::Statement u(db, "UPDATE checkpoint_pieces SET bytes = ? WHERE n = 0");
    u.bind(1, blob.data(), static_cast<int>(blob.size()));
    u.exec();
  }
  Harness h(test_manager_config(), open_sqlite_store(dir.path.string()));
  EXPECT_EQ(h.state(id), "failed");
}

}  // namespace
}  // namespace tally::test
