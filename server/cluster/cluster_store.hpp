#pragma once
// The cluster's Redis operations, typed: every command the coordinator (RedisExecutor,
// ClusterMonitor) and tally-worker send about jobs, passes, entries and workers, over
// the layout of redis_layout.hpp. Callers pass their own connection (one per thread,
// RedisConn) and decide what to do when it drops (RedisIoError); nothing here retries.
// Error replies throw RedisReplyError unless a function says otherwise.
#include <chrono>
#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "server/cluster/assets.hpp"
#include "server/cluster/redis_conn.hpp"
#include "server/cluster/redis_layout.hpp"

namespace tally::cluster {

// ================================================================ coordinator

// Publishes the coordinator's lease for workers (tally:config lease_ms).
void announce_lease(RedisConn& conn, std::chrono::milliseconds lease);
// Empties every active set (kActive and the pools'): the coordinator's first connect.
void clear_active_sets(RedisConn& conn);
// Wakes the coordinator's BLPOP (kWakeMarker on kNotify).
void push_wake_marker(RedisConn& conn);
// Announces that a job's pass may be complete (the coordinator looks at it next step).
void notify_job(RedisConn& conn, std::string_view id);

struct Notified {
  bool woken = false;             // the wait ended by a push (a job or the waker), not its timeout
  std::vector<std::string> jobs;  // job ids pushed (markers left out)
};
// Blocks on kNotify for `timeout_s` (a Redis timeout, e.g. "0.01"), then takes the rest
// of the list in the same round trip count (LPOP with a count: Redis 6.2).
Notified wait_notified(RedisConn& conn, std::string_view timeout_s);

// Deletes the keys of the job's other runs (older epochs, a cancelled run) and takes
// their streams out of `active`.
void sweep_other_runs(RedisConn& conn, std::string_view id, std::string_view run, std::string_view active);

struct JobRecord {
  std::string_view id, run, spec, manifest, spec_mac;
  unsigned max_failures = 3;
};
// The job hash for a run (clears failed/mismatch marks) and its assets (SET NX).
void write_job(RedisConn& conn, const JobRecord& job, const std::map<std::string, JobAsset>& assets);

// The result index's fields: the first slots of the entries stored so far.
std::vector<std::string> stored_entry_slots(RedisConn& conn, const PassKeys& pass);

struct PassPublication {
  size_t blocks = 0, entries = 0, group_blocks = 1;
  std::string_view input;
  std::vector<std::pair<std::string, std::string>> new_entries;  // first slot, encoded blocks
};
// The pass hash, a fresh stream with its group and the entries, the stream in `active`
// and a wake-up for idle workers, in one round trip.
void publish_pass(RedisConn& conn, const PassKeys& keys, std::string_view active, std::string_view id,
                  const PassPublication& pub);

struct PassProbe {
  const PassKeys* keys;
  std::string job_key;
};
struct PassState {
  std::optional<long long> entries_stored;  // HLEN of the index
  std::optional<bool> stream_exists;
  bool job_hash_read = false;  // the job hash's fields below were read
  std::optional<std::string> failed, mismatch, run;
};
// One round trip for all passes: how far each is, and its job's marks.
std::vector<PassState> probe_passes(RedisConn& conn, const std::vector<PassProbe>& probes);

// The stored results of the entries at these first slots and their digests (nullopt:
// not stored), in one round trip.
struct StoredEntry {
  std::optional<std::string> results, digest;
};
std::vector<StoredEntry> read_entry_values(RedisConn& conn, const PassKeys& pass, const std::vector<size_t>& first_slots);
// The workers' measured compute time per block of the job (compute_s / computed), 0
// before any was measured. Throws std::exception on a malformed field.
double measured_block_seconds(RedisConn& conn, std::string_view id);

// A merged pass's keys go in one round trip: out of `active`, its stream, hash, index,
// failures and values in one DEL (a store sees all or none), and the digests of the
// passes in `old_digests`. Returns the error replies (logged by the caller).
std::vector<std::string> drop_merged_pass(RedisConn& conn, const PassKeys& pass, std::string_view active,
                                          const std::vector<size_t>& entry_slots,
                                          const std::vector<PassKeys>& old_digests);
// A job leaves: marked cancelled (late stores are stale), every key of the passes it
// has out, its digests and its hash deleted.
void delete_job(RedisConn& conn, std::string_view id, const std::vector<PassKeys>& passes,
                const std::vector<PassKeys>& digests, std::string_view active);

struct PendingDelivery {
  long long deliveries = 0;
  std::string consumer;
};
struct PassFlight {
  uint64_t entries_pending = 0;  // entries handed out and not acked
  uint64_t redelivered = 0;      // the job's redelivered blocks
  uint64_t blocks_done = 0;      // blocks stored
  std::vector<PendingDelivery> oldest;  // up to 50 pending entries, with their delivery counts
};
// One round trip: what is in flight for each pass.
std::vector<PassFlight> probe_flight(RedisConn& conn, const std::vector<PassProbe>& probes);

// INFO memory: used_memory and maxmemory (0 = no limit).
struct RedisMemory {
  uint64_t used = 0, max = 0;
};
RedisMemory read_memory(RedisConn& conn);

struct StoreCounters {
  uint64_t first = 0, dup_equal = 0, dup_differ = 0, stale = 0, failures = 0;
};
std::optional<StoreCounters> read_store_counters(RedisConn& conn);

struct WorkerRecord {
  std::string name, host, current_job;
  std::vector<std::string> pools;  // empty: the worker takes jobs without a pool only
  unsigned threads = 0;
  double last_heartbeat = 0;  // unix seconds
  uint64_t blocks_done = 0;
};
// The registry: forgets entries older than `forget_before`, reads the rest (malformed
// entries skipped).
std::vector<WorkerRecord> read_worker_registry(RedisConn& conn, double forget_before);

// ================================================================ worker

std::optional<long long> read_lease_ms(RedisConn& conn);
bool keep_lease(RedisConn& conn, const std::string& sha, std::string_view stream, std::string_view entry,
                std::string_view consumer);
// The registry entry (expires after `ttl_s`) and its heartbeat.
void write_heartbeat(RedisConn& conn, const WorkerRecord& w, long long ttl_s);
void leave_registry(RedisConn& conn, std::string_view name);

// The id of the newest wake-up ("0-0": none yet).
std::string last_wake_id(RedisConn& conn);
// Waits up to `wait` for a wake-up after `after`; the newest one's id, or nullopt.
std::optional<std::string> wait_wake(RedisConn& conn, std::chrono::milliseconds wait, std::string_view after);
// The streams a worker in `pools` reads: kActive and each pool's set.
std::vector<std::string> active_streams(RedisConn& conn, const std::vector<std::string>& pools);

struct StreamEntry {
  std::string id, blocks, slot;  // slot empty: malformed
};
// XREADGROUP ... COUNT 1 for `consumer`: the entry handed out, or nullopt (none, or the
// stream or its group is gone).
std::optional<StreamEntry> read_entry(RedisConn& conn, std::string_view stream, std::string_view consumer);
struct Reclaim {
  bool ok = false;  // false: the stream or group is gone
  std::optional<StreamEntry> entry;
  std::string cursor;
};
// XAUTOCLAIM of one entry idle longer than `idle_ms`, from `cursor`.
Reclaim reclaim_entry(RedisConn& conn, std::string_view stream, std::string_view consumer, long long idle_ms,
                      std::string_view cursor);
// Acks an entry that will not be computed (NOGROUP ignored).
void skip_entry(RedisConn& conn, std::string_view stream, std::string_view entry_id);
void count_redelivery(RedisConn& conn, std::string_view id);

struct JobSource {
  std::optional<std::string> spec;
  std::string manifest;  // "" = no assets
  std::string spec_mac;  // "" = none written
};
JobSource read_job_source(RedisConn& conn, std::string_view id);

// The job's current run, whether it is cancelled, and its max_failures (nullopt: none).
struct RunState {
  std::string run;
  bool cancelled = false;
  std::optional<std::string> max_failures;
};
std::optional<RunState> read_run_state(RedisConn& conn, std::string_view id);

struct PassMeta {
  uint64_t entries = 0;  // stream entries the pass is cut into (its result fields)
  std::string input;
  uint64_t group_blocks = 1;  // result groups: result_groups(an entry's blocks, this)
};
std::optional<PassMeta> read_pass_meta(RedisConn& conn, const PassKeys& pass);

struct EntryStore {
  const PassKeys* keys;
  std::string_view job_id, run, slot, entry_id, upload;
  uint64_t pass_entries = 0;
  double compute_seconds = 0;
  size_t blocks = 0;
  std::string_view digest, results;
};
struct StoreOutcome {
  long long first = 0, dup_equal = 0, dup_differ = 0, stale = 0;  // in blocks
};
// With the store: read the stream's next entry for `consumer` and the job's run state.
struct ReadOn {
  std::string_view stream, consumer, job_id;
  std::optional<StreamEntry> entry;
  std::optional<RunState> run;  // set when read
};
// The store script (kStoreScript) in one round trip: inline results below kUploadBytes,
// else SET at the upload key first in the same pipeline; reloads the script once if
// Redis forgot it. `read_on`, if given and without an entry yet, is read in the same
// round trip. Throws RedisReplyError (its text starts with kUploadMissing when the
// upload was lost) or RedisIoError.
StoreOutcome store_entry(RedisConn& conn, const std::string& sha, const EntryStore& e, ReadOn* read_on);

struct EntryFailure {
  const PassKeys* keys;
  std::string_view job_id, run, entry_id, slot, max_failures, message, blocks;
};
// The fail script (kFailScript): 0 stale, 1 re-queued, 2 the job failed.
long long fail_entry(RedisConn& conn, const std::string& sha, const EntryFailure& f);

// A scene file's bytes (tally:asset:{sha}), nullopt if missing.
std::optional<std::string> read_asset(RedisConn& conn, std::string_view sha);

}  // namespace tally::cluster
