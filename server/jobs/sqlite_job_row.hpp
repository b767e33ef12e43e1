#pragma once
// One reader of a jobs-table row, shared by the live SQLite store and the salvage of
// a damaged file, so that a column added to the table is read back by both (the
// salvage once had its own copy, which missed the facts column: salvaged finished
// jobs lost their RunFacts).
#include <SQLiteCpp/SQLiteCpp.h>

#include <optional>
#include <string>

#include "server/jobs/job_store.hpp"

namespace tally {

// The columns added to the jobs table after its first release: a file written
// before them has them only once its migration has run.
struct JobTableColumns {
  bool owner = true;  // access control
  bool facts = true;  // finished jobs' RunFacts
};

// Which of the later columns `db`'s jobs table has (PRAGMA table_info).
JobTableColumns job_table_columns(SQLite::Database& db);

// The select list that read_job_row reads, in its order; a column the table lacks
// reads as ''. A query's further columns (the checkpoint, sizes) start at index
// kJobRowColumnCount.
std::string job_row_columns(JobTableColumns have = {});
inline constexpr int kJobRowColumnCount = 13;

// The StoredJob of the current row (without checkpoint and stored_bytes).
StoredJob read_job_row(const SQLite::Statement& q);

// A job's checkpoint as stored since checkpoints outgrew one BLOB (SQLite refuses one
// over 1e9 bytes, a 1080p image's is 1.2 GB): rows of checkpoint_pieces, joined in
// order; nullopt when it has none (or `db` has no such table: a file of before them).
std::optional<std::string> read_checkpoint_pieces(SQLite::Database& db, const std::string& id);

// A BLOB column's bytes, nullopt for NULL.
std::optional<std::string> read_blob(const SQLite::Column& c);

}  // namespace tally
