#pragma once
// Where jobs live between restarts. The server talks to this interface only, so a
// store shared by several servers can replace the embedded SQLite one later.
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "common/engine/checkpoint.hpp"

namespace tally {

// Streams a checkpoint to a store's sink in pieces (write_checkpoint of the job's state,
// read in place): returns its size.
using CheckpointStream = std::function<uint64_t(const CheckpointSink& sink)>;

struct StoredJob {
  std::string id;
  int64_t seq = 0;            // submission order
  std::string spec;           // the job spec as submitted (JSON text)
  int priority = 0;
  std::string owner;          // submitting principal ("" without access control)
  std::string state;          // queued | running | succeeded | failed | cancelled
  std::string stop_rule;      // current rule (JSON), which extend may have changed
  std::string error;          // failure message, "" if none
  std::string result;         // final status JSON of a finished job, "" otherwise
  std::optional<std::string> checkpoint;  // encode_checkpoint bytes; nullopt on save = keep
                                          // (load_all: unfinished jobs only; see load_checkpoint)
  // On save, instead of `checkpoint`: the checkpoint written piece by piece as the store
  // takes it (a store holds no more than a piece of it in memory). Ignored on load.
  CheckpointStream checkpoint_stream;
  std::string facts;          // a finished job's RunFacts (run_facts_json), "" if none
  uint64_t stored_bytes = 0;  // load_all: bytes the row takes (spec, result, checkpoint)
  double created_at = 0, started_at = 0, finished_at = 0;  // unix seconds, 0 = not yet
};

class JobStore {
 public:
  virtual ~JobStore() = default;
  // Insert or update one job atomically. A nullopt checkpoint (and no checkpoint_stream)
  // keeps the stored one.
  virtual void save(const StoredJob& job) = 0;
  // Every job, in submission order. Checkpoints only of unfinished jobs (queued,
  // running): a finished job's state stays on disk until asked for.
  virtual std::vector<StoredJob> load_all() = 0;
  // One job's checkpoint (nullopt if the job or its checkpoint is not stored).
  virtual std::optional<std::string> load_checkpoint(const std::string& id) = 0;
  // Deletes the job and its checkpoint; false if it was not stored.
  virtual bool remove(const std::string& id) = 0;
  // Counts server starts; event ids are made unique across restarts with it.
  virtual uint64_t next_epoch() = 0;
  // A small durable write that says whether the store takes writes (again, after a full
  // disk): throws as save does while it does not. The recorder calls it off the request
  // threads while the last save failed and no failed save waits to be retried, so
  // readiness recovers without a submit. False: this store has no such write (then only
  // a save clears the failure).
  virtual bool probe() { return false; }
  // Set when the store was found damaged at open and salvaged: what was moved
  // aside and what was lost (one line for the log and /readyz).
  virtual std::optional<std::string> damage() const { return std::nullopt; }
};

// The embedded default: <data_dir>/tally.db, WAL mode. A damaged file (its pages
// fail SQLite's quick_check, or it is not a database) does not stop the server:
// it is moved aside and what can be read is salvaged into a fresh one
// (sqlite_salvage.hpp); damage() then says what was lost.
std::unique_ptr<JobStore> open_sqlite_store(const std::string& data_dir);

// For tests and --data-dir ":memory:"-like use.
std::unique_ptr<JobStore> make_memory_store();

}  // namespace tally
