#pragma once
// What the server does with a damaged tally.db instead of refusing to start:
// move it aside for the operator (tally.db.damaged-<UTC time>, with its -wal and
// -shm) and read back every row that can still be read, one row at a time (a
// damaged page loses the rows on it, not the table). Debian 12's libsqlite3
// (3.40) does not ship the sqlite3_recover API, so this is per-row reads.
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "server/jobs/job_store.hpp"

namespace tally {

struct SalvageResult {
  std::string quarantined;         // where the damaged file now is
  std::vector<StoredJob> jobs;     // rows read back whole (or without their checkpoint, see partial)
  std::vector<std::string> partial;  // ids read back without their checkpoint
  std::vector<std::string> lost;   // ids not recovered ("row N" when even the id is unreadable)
  std::optional<uint64_t> epoch;   // the start counter, if it could be read
  // One line for the log and /readyz.
  std::string summary(const std::string& cause) const;
};

// True for SQLite errors that mean the file is damaged (SQLITE_CORRUPT, SQLITE_NOTADB).
bool is_damage_error(int sqlite_error_code);

// Renames `db_path` (and its -wal, -shm) to `db_path`.damaged-<time> and reads what
// it can from the renamed file. Never throws for damage; throws std::runtime_error
// if the file cannot be moved aside.
SalvageResult quarantine_and_salvage(const std::string& db_path);

}  // namespace tally
