#include "server/jobs/sqlite_salvage.hpp"

#include <SQLiteCpp/SQLiteCpp.h>
#include <fmt/format.h>
#include <sqlite3.h>

#include <algorithm>
#include <ctime>
#include <filesystem>
#include <map>
#include <set>

#include "common/log/log.hpp"
#include "server/jobs/sqlite_job_row.hpp"

namespace tally {

namespace fs = std::filesystem;

namespace {

std::string utc_stamp() {
  const std::time_t t = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buf[32];
  std::strftime(buf, sizeof buf, "%Y%m%dT%H%M%SZ", &tm);
  return buf;
}

// Scans rowids in one direction until the first error (a damaged page stops a scan;
// scanning from both ends gets past one damaged region).
void scan_rowids(SQLite::Database& db, const char* sql, std::set<int64_t>& out) {
  try {
    SQLite::Statement q(db, sql);
    while (q.executeStep()) out.insert(q.getColumn(0).getInt64());
  } catch (const SQLite::Exception&) {
    // expected at the damaged page: what was read so far is kept
  }
}

}  // namespace

bool is_damage_error(int code) {
  const int primary = code & 0xff;
  return primary == SQLITE_CORRUPT || primary == SQLITE_NOTADB;
}

std::string SalvageResult::summary(const std::string& cause) const {
  std::string s = fmt::format("the job database was damaged ({}); it was moved aside to {} and {} job(s) were recovered",
                              cause, quarantined, jobs.size());
  if (!partial.empty()) {
    s += fmt::format(", {} of them without their checkpoint (they restart from scratch or keep their stored result): {}",
                     partial.size(), fmt::join(partial, ", "));
  }
  s += lost.empty() ? "; nothing known was lost" : fmt::format("; lost: {}", fmt::join(lost, ", "));
  if (!epoch) s += "; the start counter was lost (a new one was chosen from the clock)";
  return s;
}

SalvageResult quarantine_and_salvage(const std::string& db_path) {
  SalvageResult r;
  std::string target = db_path + ".damaged-" + utc_stamp();
  for (int n = 1; fs::exists(target); ++n) target = fmt::format("{}.damaged-{}-{}", db_path, utc_stamp(), n);
  std::error_code ec;
  fs::rename(db_path, target, ec);
  if (ec) throw std::runtime_error(fmt::format("cannot move the damaged job database {} aside: {}", db_path, ec.message()));
  for (const char* side : {"-wal", "-shm"}) {
    if (fs::exists(db_path + side)) {
      fs::rename(db_path + side, target + side, ec);
      if (ec) log::warn("cannot move {}{} aside: {}", db_path, side, ec.message());
    }
  }
  r.quarantined = fs::absolute(target).string();

  std::optional<SQLite::Database> db;
  try {
    db.emplace(target, SQLite::OPEN_READONLY);
  } catch (const SQLite::Exception& e) {
    log::error("the damaged job database {} cannot be opened at all: {}", target, e.what());
    r.lost.push_back("every job (the file cannot be opened)");
    return r;
  }
  try {
    SQLite::Statement q(*db, "SELECT value FROM meta WHERE key = 'epoch'");
    if (q.executeStep()) r.epoch = static_cast<uint64_t>(q.getColumn(0).getInt64());
  } catch (const SQLite::Exception&) {
    // lost with its page; the caller picks a safe epoch
  }

  // Which rows exist: the id index names them (rowid → id) even where the table's
  // own page is gone; the table scanned from both ends gives the rest.
  std::map<int64_t, std::string> index_ids;
  for (const char* order : {"ASC", "DESC"}) {
    try {
      SQLite::Statement q(*db, fmt::format("SELECT rowid, id FROM jobs INDEXED BY sqlite_autoindex_jobs_1 ORDER BY id {}",
                                           order));
      while (q.executeStep()) index_ids[q.getColumn(0).getInt64()] = q.getColumn(1).getString();
    } catch (const SQLite::Exception&) {
      // the index is damaged too, or the table is: keep what was read
    }
  }
  std::set<int64_t> rowids;
  scan_rowids(*db, "SELECT rowid FROM jobs NOT INDEXED ORDER BY rowid ASC", rowids);
  scan_rowids(*db, "SELECT rowid FROM jobs NOT INDEXED ORDER BY rowid DESC", rowids);
  int64_t max_rowid = rowids.empty() ? 0 : *rowids.rbegin();
  if (!index_ids.empty()) max_rowid = std::max(max_rowid, index_ids.rbegin()->first);

  // Every rowid up to the largest seen, one at a time: the ones in a damaged page
  // fail alone. A row whose checkpoint is unreadable is kept without it.
  // A file whose migration never ran lacks the later columns: they read as ''.
  JobTableColumns have;
  try {
    have = job_table_columns(*db);
  } catch (const SQLite::Exception& e) {
    log::warn("the damaged job database's columns cannot be listed ({}); reading every column", e.what());
  }
  const std::string columns = job_row_columns(have);
  SQLite::Statement whole(*db, fmt::format("SELECT {}, checkpoint FROM jobs NOT INDEXED WHERE rowid = ?", columns));
  SQLite::Statement light(*db, fmt::format("SELECT {} FROM jobs NOT INDEXED WHERE rowid = ?", columns));
  for (int64_t rowid = 1; rowid <= max_rowid; ++rowid) {
    try {
      whole.tryReset();
      whole.bind(1, rowid);
      if (!whole.executeStep()) continue;  // no such row: never existed or deleted
      StoredJob j = read_job_row(whole);
      j.checkpoint = read_blob(whole.getColumn(kJobRowColumnCount));
      if (!j.checkpoint) j.checkpoint = read_checkpoint_pieces(*db, j.id);
      r.jobs.push_back(std::move(j));
      continue;
    } catch (const SQLite::Exception&) {
      // try the row without its checkpoint below
    }
    try {
      light.tryReset();
      light.bind(1, rowid);
      if (light.executeStep()) {
        StoredJob j = read_job_row(light);
        r.partial.push_back(j.id);
        r.jobs.push_back(std::move(j));
        continue;
      }
    } catch (const SQLite::Exception&) {
      // the row itself is gone
    }
    if (auto it = index_ids.find(rowid); it != index_ids.end()) {
      r.lost.push_back(it->second);
    } else {
      // Unreadable and unnamed: a row that was there, or a gap in the rowids that
      // falls in the damaged page (the two cannot be told apart).
      r.lost.push_back(fmt::format("row {} (id unreadable)", rowid));
    }
  }
  std::sort(r.jobs.begin(), r.jobs.end(), [](const StoredJob& a, const StoredJob& b) { return a.seq < b.seq; });
  return r;
}

}  // namespace tally
