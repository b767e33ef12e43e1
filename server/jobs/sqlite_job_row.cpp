#include "server/jobs/sqlite_job_row.hpp"

#include <fmt/format.h>

namespace tally {

JobTableColumns job_table_columns(SQLite::Database& db) {
  JobTableColumns have{false, false};
  SQLite::Statement q(db, "PRAGMA table_info(jobs)");
  while (q.executeStep()) {
    const std::string name = q.getColumn(1).getString();
    have.owner = have.owner || name == "owner";
    have.facts = have.facts || name == "facts";
  }
  return have;
}

std::string job_row_columns(JobTableColumns have) {
  return fmt::format("id, seq, spec, priority, state, stop_rule, error, result, created_at, started_at, finished_at, "
                     "{}, {}",
                     have.owner ? "owner" : "'' AS owner", have.facts ? "facts" : "'' AS facts");
}

StoredJob read_job_row(const SQLite::Statement& q) {
  StoredJob j;
  j.id = q.getColumn(0).getString();
  j.seq = q.getColumn(1).getInt64();
  j.spec = q.getColumn(2).getString();
  j.priority = q.getColumn(3).getInt();
  j.state = q.getColumn(4).getString();
  j.stop_rule = q.getColumn(5).getString();
  j.error = q.getColumn(6).getString();
  j.result = q.getColumn(7).getString();
  j.created_at = q.getColumn(8).getDouble();
  j.started_at = q.getColumn(9).getDouble();
  j.finished_at = q.getColumn(10).getDouble();
  j.owner = q.getColumn(11).getString();
  j.facts = q.getColumn(12).getString();
  return j;
}

std::optional<std::string> read_checkpoint_pieces(SQLite::Database& db, const std::string& id) {
  if (!db.tableExists("checkpoint_pieces")) return std::nullopt;
  SQLite::Statement size(db, "SELECT count(*), COALESCE(SUM(length(bytes)), 0) FROM checkpoint_pieces WHERE id = ?");
  size.bind(1, id);
  if (!size.executeStep() || size.getColumn(0).getInt64() == 0) return std::nullopt;
  std::string out;
  out.reserve(static_cast<size_t>(size.getColumn(1).getInt64()));
  SQLite::Statement q(db, "SELECT bytes FROM checkpoint_pieces WHERE id = ? ORDER BY n");
  q.bind(1, id);
  while (q.executeStep()) {
    const SQLite::Column c = q.getColumn(0);
    out.append(static_cast<const char*>(c.getBlob()), static_cast<size_t>(c.getBytes()));
  }
  return out;
}

std::optional<std::string> read_blob(const SQLite::Column& c) {
  if (c.isNull()) return std::nullopt;
  return std::string(static_cast<const char*>(c.getBlob()), static_cast<size_t>(c.getBytes()));
}

}  // namespace tally
