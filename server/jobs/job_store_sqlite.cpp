#include <SQLiteCpp/SQLiteCpp.h>
#include <fmt/format.h>

#include <algorithm>
#include <ctime>
#include <filesystem>
#include <mutex>
#include <string_view>

#include "common/log/log.hpp"
#include "server/jobs/checkpoint_spool.hpp"
#include "server/jobs/job_store.hpp"
#include "server/jobs/sqlite_job_row.hpp"
#include "server/jobs/sqlite_salvage.hpp"

namespace tally {

namespace {

class SqliteJobStore final : public JobStore {
 public:
  explicit SqliteJobStore(const std::string& path)
      : db_(path, SQLite::OPEN_READWRITE | SQLite::OPEN_CREATE | SQLite::OPEN_FULLMUTEX),
        dir_(std::filesystem::absolute(path).parent_path()) {
    db_.exec("PRAGMA journal_mode=WAL");
    // NORMAL is durable against a crashed or killed process (not power loss) and
    // far cheaper than FULL; checkpoints are small and frequent.
    db_.exec("PRAGMA synchronous=NORMAL");
    db_.exec("PRAGMA busy_timeout=5000");
    db_.exec(
        "CREATE TABLE IF NOT EXISTS jobs ("
        " id TEXT PRIMARY KEY, seq INTEGER NOT NULL, spec TEXT NOT NULL, priority INTEGER NOT NULL,"
        " state TEXT NOT NULL, stop_rule TEXT NOT NULL, error TEXT NOT NULL DEFAULT '',"
        " result TEXT NOT NULL DEFAULT '', checkpoint BLOB,"
        " created_at REAL NOT NULL, started_at REAL NOT NULL, finished_at REAL NOT NULL,"
        " updated_at REAL NOT NULL DEFAULT ((julianday('now') - 2440587.5) * 86400.0),"
        " owner TEXT NOT NULL DEFAULT '')");
    db_.exec("CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value INTEGER NOT NULL)");
    // A checkpoint in pieces of kCheckpointPieceBytes (n = 0, 1, ...): one BLOB may not
    // exceed 1e9 bytes, and a save streams the pieces in as they are encoded. The jobs
    // table's checkpoint column holds those of files written before (read, never written).
    db_.exec("CREATE TABLE IF NOT EXISTS checkpoint_pieces (id TEXT NOT NULL, n INTEGER NOT NULL,"
             " bytes BLOB NOT NULL, PRIMARY KEY (id, n))");
    migrate();
  }

  // "" if SQLite's quick_check (every page's structure) finds nothing wrong.
  std::string check() {
    std::string problems;
    SQLite::Statement q(db_, "PRAGMA quick_check(5)");
    while (q.executeStep()) {
      const std::string line = q.getColumn(0).getString();
      if (line != "ok") problems += (problems.empty() ? "" : "; ") + line;
    }
    return problems;
  }

  // A start counter at least `epoch` (salvage: the old one, or one from the clock).
  void set_epoch(uint64_t epoch) {
    std::lock_guard lock(mu_);
    SQLite::Statement st(db_, "INSERT INTO meta (key, value) VALUES ('epoch', ?)"
                              " ON CONFLICT(key) DO UPDATE SET value = MAX(value, excluded.value)");
    st.bind(1, static_cast<int64_t>(epoch));
    st.exec();
  }

  void set_damage(std::string note) { damage_ = std::move(note); }
  std::optional<std::string> damage() const override { return damage_; }

  // Databases written before access control have no owner column: their jobs
  // belong to the anonymous owner "" (visible to admins only once auth is on).
  // Databases written before finished jobs kept their state on disk have no facts
  // column: their finished jobs' facts are rebuilt once from the checkpoint.
  void migrate() {
    const JobTableColumns have = job_table_columns(db_);
    if (!have.owner) db_.exec("ALTER TABLE jobs ADD COLUMN owner TEXT NOT NULL DEFAULT ''");
    if (!have.facts) db_.exec("ALTER TABLE jobs ADD COLUMN facts TEXT NOT NULL DEFAULT ''");
  }

  void save(const StoredJob& j) override {
    // A streamed checkpoint is encoded before the lock (checkpoint_spool.hpp): other
    // saves wait for its copy into the database, not for its encoding.
    std::optional<CheckpointSpool> spool;
    if (!j.checkpoint && j.checkpoint_stream) spool.emplace(dir_, j.checkpoint_stream);
    std::lock_guard lock(mu_);
    SQLite::Transaction tx(db_);
    SQLite::Statement st(db_,
                         "INSERT INTO jobs (id, seq, spec, priority, state, stop_rule, error, result,"
                         " checkpoint, created_at, started_at, finished_at, owner, facts) VALUES (?,?,?,?,?,?,?,?,?,?,?,?,?,?)"
                         " ON CONFLICT(id) DO UPDATE SET priority=excluded.priority, state=excluded.state, stop_rule=excluded.stop_rule,"
                         " error=excluded.error, result=excluded.result, facts=excluded.facts,"
                         " checkpoint=COALESCE(excluded.checkpoint, jobs.checkpoint),"
                         " started_at=excluded.started_at, finished_at=excluded.finished_at,"
                         " updated_at=(julianday('now') - 2440587.5) * 86400.0");
    st.bind(1, j.id);
    st.bind(2, static_cast<int64_t>(j.seq));
    st.bind(3, j.spec);
    st.bind(4, j.priority);
    st.bind(5, j.state);
    st.bind(6, j.stop_rule);
    st.bind(7, j.error);
    st.bind(8, j.result);
    st.bind(9);  // NULL: the legacy column keeps what it had, unless replaced below
    st.bind(10, j.created_at);
    st.bind(11, j.started_at);
    st.bind(12, j.finished_at);
    st.bind(13, j.owner);
    st.bind(14, j.facts);
    st.exec();
    if (j.checkpoint || spool) write_pieces(j, spool ? &*spool : nullptr);
    tx.commit();
  }

  // Replaces the job's checkpoint by j's (or the spooled one), in pieces (inside save's
  // transaction).
  void write_pieces(const StoredJob& j, CheckpointSpool* spool) {
    SQLite::Statement legacy(db_, "UPDATE jobs SET checkpoint = NULL WHERE id = ?");
    legacy.bind(1, j.id);
    legacy.exec();
    SQLite::Statement drop(db_, "DELETE FROM checkpoint_pieces WHERE id = ?");
    drop.bind(1, j.id);
    drop.exec();
    SQLite::Statement put(db_, "INSERT INTO checkpoint_pieces (id, n, bytes) VALUES (?, ?, ?)");
    int64_t n = 0;
    const auto sink = [&](std::string_view piece) {
      put.reset();
      put.bind(1, j.id);
      put.bind(2, n++);
      // Not copied by the binding (SQLite copies it into its pages); "" for an empty
      // piece, since a null pointer would bind NULL.
      put.bindNoCopy(3, piece.empty() ? "" : piece.data(), static_cast<int>(piece.size()));
      put.exec();
    };
    if (j.checkpoint) {
      const std::string_view all(*j.checkpoint);
      for (size_t at = 0; at < all.size(); at += kCheckpointPieceBytes) sink(all.substr(at, kCheckpointPieceBytes));
    } else {
      spool->replay(kCheckpointPieceBytes, sink);
    }
    if (n == 0) sink({});  // an empty checkpoint is still one
  }

  std::optional<std::string> checkpoint_of(const std::string& id, std::optional<std::string> legacy) {
    if (legacy) return legacy;
    return read_checkpoint_pieces(db_, id);
  }

  std::vector<StoredJob> load_all() override {
    std::lock_guard lock(mu_);
    std::vector<StoredJob> out;
    SQLite::Statement q(db_, fmt::format("SELECT {},"
                                         " CASE WHEN state IN ('queued', 'running') THEN checkpoint END,"
                                         " length(spec) + length(result) + length(facts) + COALESCE(length(checkpoint), 0)"
                                         " + (SELECT COALESCE(SUM(length(p.bytes)), 0) FROM checkpoint_pieces p"
                                         " WHERE p.id = jobs.id)"
                                         " FROM jobs ORDER BY seq",
                                         job_row_columns()));
    while (q.executeStep()) {
      StoredJob j = read_job_row(q);
      j.checkpoint = read_blob(q.getColumn(kJobRowColumnCount));
      if (j.state == "queued" || j.state == "running") j.checkpoint = checkpoint_of(j.id, std::move(j.checkpoint));
      j.stored_bytes = static_cast<uint64_t>(q.getColumn(kJobRowColumnCount + 1).getInt64());
      out.push_back(std::move(j));
    }
    return out;
  }

  std::optional<std::string> load_checkpoint(const std::string& id) override {
    std::lock_guard lock(mu_);
    SQLite::Statement q(db_, "SELECT checkpoint FROM jobs WHERE id = ?");
    q.bind(1, id);
    if (!q.executeStep()) return std::nullopt;
    return checkpoint_of(id, read_blob(q.getColumn(0)));
  }

  bool remove(const std::string& id) override {
    std::lock_guard lock(mu_);
    SQLite::Transaction tx(db_);
    SQLite::Statement pieces(db_, "DELETE FROM checkpoint_pieces WHERE id = ?");
    pieces.bind(1, id);
    pieces.exec();
    SQLite::Statement st(db_, "DELETE FROM jobs WHERE id = ?");
    st.bind(1, id);
    const bool removed = st.exec() > 0;
    tx.commit();
    return removed;
  }

  bool probe() override {
    std::lock_guard lock(mu_);
    SQLite::Transaction tx(db_);
    db_.exec("INSERT INTO meta (key, value) VALUES ('probe', 1)"
             " ON CONFLICT(key) DO UPDATE SET value = value + 1");
    tx.commit();
    return true;
  }

  uint64_t next_epoch() override {
    std::lock_guard lock(mu_);
    SQLite::Transaction tx(db_);
    db_.exec("INSERT INTO meta (key, value) VALUES ('epoch', 1)"
             " ON CONFLICT(key) DO UPDATE SET value = value + 1");
    const int64_t e = db_.execAndGet("SELECT value FROM meta WHERE key = 'epoch'").getInt64();
    tx.commit();
    return static_cast<uint64_t>(e);
  }

 private:
  std::mutex mu_;
  SQLite::Database db_;
  std::filesystem::path dir_;  // the database's directory: checkpoints spool there
  std::optional<std::string> damage_;
};

std::unique_ptr<SqliteJobStore> salvage(const std::string& path, const std::string& cause) {
  log::error("the job database {} is damaged ({}); moving it aside and salvaging what can be read", path, cause);
  SalvageResult r = quarantine_and_salvage(path);
  auto store = std::make_unique<SqliteJobStore>(path);
  for (const StoredJob& j : r.jobs) store->save(j);
  // Event ids must keep growing across restarts: with the counter lost, the clock
  // (seconds since 1970) is larger than any count of starts.
  store->set_epoch(r.epoch ? *r.epoch : static_cast<uint64_t>(std::time(nullptr)));
  const std::string note = r.summary(cause);
  log::error("{}", note);
  store->set_damage(note);
  return store;
}

}  // namespace

std::unique_ptr<JobStore> open_sqlite_store(const std::string& data_dir) {
  std::filesystem::create_directories(data_dir);
  const std::string path = (std::filesystem::path(data_dir) / "tally.db").string();
  try {
    std::unique_ptr<SqliteJobStore> store;
    std::string damage;
    try {
      store = std::make_unique<SqliteJobStore>(path);
      damage = store->check();
    } catch (const SQLite::Exception& e) {
      if (!is_damage_error(e.getErrorCode()) && !is_damage_error(e.getExtendedErrorCode())) throw;
      damage = e.what();
    }
    if (damage.empty()) return store;
    store.reset();  // closed before it is moved aside
    return salvage(path, damage);
  } catch (const std::exception& e) {
    // SQLite's messages ("attempt to write a readonly database", "unable to open
    // database file") name no file: the operator needs the path.
    throw std::runtime_error(fmt::format("cannot open the job database {}: {} (the data dir must be a writable "
                                         "directory)",
                                         std::filesystem::absolute(path).string(), e.what()));
  }
}

}  // namespace tally
