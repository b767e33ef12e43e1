#pragma once
// The cluster's Redis layout: the key names, the stream-key grammar and the three Lua
// scripts. Data only; the operations on it (what the coordinator and tally-worker send)
// are cluster_store.hpp, the one place that speaks to Redis about jobs. docs/cluster.md
// describes the layout in prose.
//
//   tally:job:{id}                  hash: run, cancelled, spec, assets, spec_mac (result_key.hpp),
//                                   max_failures,
//                                   failed (error text), mismatch, redelivered,
//                                   compute_s + computed (workers' seconds and blocks)
//   tally:s:{id}:{run}:{pass}       stream of the pass's blocks, k consecutive ones per
//                                   entry (b = blocks, s = first slot), consumer group "w"
//   tally:p:{id}:{run}:{pass}       hash: n (blocks in the pass), e (entries in the pass),
//                                   input (pass input bytes), g (result group size: an
//                                   entry's results are one per result_groups(its
//                                   blocks, g)), done (blocks stored)
//   tally:r:{id}:{run}:{pass}       hash: first slot of an entry -> "1" once its results are
//                                   stored (one field per entry; first wins; HLEN = entries done)
//   tally:v:{id}:{run}:{pass}:{slot} string: the results of the entry at first slot `slot`
//                                   (append_entry_result), deleted with the pass's other keys
//   tally:upload:{consumer}         string: large results (>= kUploadBytes) a worker thread
//                                   is about to store (SET with a TTL, then moved into place
//                                   or deleted by the store script)
//   tally:d:{id}:{run}:{pass}       hash: first slot of an entry -> sha1 of its first
//                                   results, kept a few passes longer so late duplicates
//                                   are still compared
//   tally:f:{id}:{run}:{pass}       hash: slot -> failed deliveries
//   tally:active                    set of the stream keys any worker reads (jobs without a pool)
//   tally:active:{pool}             set of the stream keys of jobs that need pool `pool`:
//                                   read by the workers started with --pool pool
//   tally:wake                      stream the coordinator appends to when work appears
//   tally:notify                    list of job ids whose pass is complete (and kWakeMarker)
//   tally:counters                  hash: first, dup_equal, dup_differ, stale, failures
//   tally:workers                   zset name -> last heartbeat (unix s)
//   tally:worker:{name}             hash: name, host, threads, heartbeat, blocks_done, current_job,
//                                   pools (comma-separated, "" = none)
//   tally:config                    hash: lease_ms (the coordinator's --lease, read by workers)
//   tally:asset:{sha256}            bytes of a scene file (OBJ, .mtl, glTF/.glb, buffer, image, map), content-addressed
//
// run = "{epoch}.{generation}": a new one each time a job enters the coordinator, so
// nothing of an older epoch, an earlier cancelled run or a previous pass is ever merged.
#include <cstddef>
#include <cstdint>
#include <string>
#include <optional>
#include <string_view>

namespace tally::cluster {

inline constexpr std::string_view kGroup = "w";
inline constexpr std::string_view kActive = "tally:active";
inline constexpr std::string_view kWake = "tally:wake";
inline constexpr std::string_view kNotify = "tally:notify";
// Pushed to kNotify by the coordinator's own waker (a job was added or cancelled): not a job id.
inline constexpr std::string_view kWakeMarker = "~wake";
inline constexpr std::string_view kCounters = "tally:counters";
inline constexpr std::string_view kWorkers = "tally:workers";
inline constexpr std::string_view kConfig = "tally:config";

// The active set a pass stream goes into: kActive for a job without a pool.
inline std::string active_key(std::string_view pool) {
  return pool.empty() ? std::string(kActive) : std::string(kActive) + ":" + std::string(pool);
}

inline std::string job_key(std::string_view id) { return "tally:job:" + std::string(id); }
inline std::string pass_key(char kind, std::string_view id, std::string_view run, uint64_t pass) {
  std::string k = "tally:";
  k += kind;
  k += ':';
  k += id;
  k += ':';
  k += run;
  k += ':';
  k += std::to_string(pass);
  return k;
}
// Where the results of the entry whose first slot is `slot` live.
inline std::string value_key(std::string_view id, std::string_view run, uint64_t pass, std::string_view slot) {
  std::string k = pass_key('v', id, run, pass);
  k += ':';
  k += slot;
  return k;
}
// One per worker thread (consumer name "{worker}/{thread}"): a thread stores one entry at a time.
inline std::string upload_key(std::string_view consumer) { return "tally:upload:" + std::string(consumer); }
// How long an upload lives if its store script never runs (the worker died between them).
inline constexpr std::string_view kUploadTtlMs = "300000";
inline std::string worker_key(std::string_view name) { return "tally:worker:" + std::string(name); }
inline std::string asset_key(std::string_view sha) { return "tally:asset:" + std::string(sha); }

// The keys of one pass of one run of a job (pass_key's kinds s, p, r, d, f, v).
struct PassKeys {
  PassKeys(std::string_view id, std::string_view run, uint64_t pass)
      : stream(pass_key('s', id, run, pass)),
        meta(pass_key('p', id, run, pass)),
        index(pass_key('r', id, run, pass)),
        digests(pass_key('d', id, run, pass)),
        failures(pass_key('f', id, run, pass)),
        id_(id),
        run_(run),
        pass_(pass) {}
  std::string stream, meta, index, digests, failures;
  std::string value(std::string_view slot) const { return value_key(id_, run_, pass_, slot); }
  std::string value(size_t slot) const { return value(std::to_string(slot)); }

 private:
  std::string id_, run_;
  uint64_t pass_;
};

// What a stream key tally:s:{id}:{run}:{pass} names; nullopt for any other string.
struct StreamKey {
  std::string id, run;
  uint64_t pass = 0;
};
std::optional<StreamKey> parse_stream_key(std::string_view key);

// An entry of a pass stream holds k consecutive blocks (fields b = k encoded blocks,
// s = slot of the first), whole result groups (PassWork::groups), whose results the
// worker combines and stores one per group: the coordinator sizes k so an entry takes ~20 ms to compute,
// and a pass keeps its partition into entries when it is published again (after a
// reconnect or a Redis restart), so an entry's first slot names the same blocks in every
// delivery.
//
// Stores an entry's results. Small results (below kUploadBytes) travel inline as the
// last argument and the script SETs them. Large ones (an image tile's, ~100-600 KB)
// would be copied into a Lua string and back out (565 µs of Redis time per call for
// ~200 KB): the worker SETs them at its upload key (with a TTL) in the same pipeline,
// and the script moves them (RENAME: O(1), no copy). Either way, if this delivery is
// the entry's first (HSETNX of its first slot into the index hash), the results land at
// the entry's value key, and the entry is acked in the same atomic step; the upload is
// gone afterwards in every case. A duplicate is compared byte for byte while the pass
// is open (the one Lua copy, on a rare path), by SHA-1 digest once it is merged. The
// worker sends the digest (result_digest, the hex of what redis.sha1hex would compute)
// so Redis does not hash the results. One key per entry, not per block: Redis does a
// few operations per entry whatever its length. Returns {first, duplicate equal,
// duplicate different, stale}, counted in blocks; a difference marks the job
// (non-determinism). Stale: the job was cancelled, belongs to another run, or its pass
// is gone without a digest. An error reply starting with kUploadMissing: the upload was
// not there (Redis restarted between the two commands): upload again.
// KEYS: results index, stream, job, digests, counters, notify, pass, upload, value
// ARGV: first slot, entry id, run, entry count of the pass, job id, compute seconds,
//       blocks in the entry, digest of the results, [the results, when inline]
inline constexpr size_t kUploadBytes = 64 * 1024;
inline constexpr std::string_view kUploadMissing = "TALLYUPLOAD";
inline constexpr std::string_view kStoreScript = R"lua(
local inline = ARGV[9]
if not inline and redis.call('EXISTS', KEYS[8]) == 0 then
  return redis.error_reply('TALLYUPLOAD the results to store are not at ' .. KEYS[8])
end
local function drop_upload()
  if not inline then redis.call('DEL', KEYS[8]) end
end
local k = tonumber(ARGV[7])
local run = redis.call('HGET', KEYS[3], 'run')
if run ~= ARGV[3] or redis.call('HGET', KEYS[3], 'cancelled') == '1' then
  drop_upload()
  redis.call('HINCRBY', KEYS[5], 'stale', k)
  return {0, 0, 0, k}
end
redis.call('HINCRBYFLOAT', KEYS[3], 'compute_s', ARGV[6])
redis.call('HINCRBY', KEYS[3], 'computed', k)
local open = redis.call('EXISTS', KEYS[2]) == 1
if open then redis.call('XACK', KEYS[2], 'w', ARGV[2]) end
local slot = ARGV[1]
local first, eq, diff, stale = 0, 0, 0, 0
if open and redis.call('HSETNX', KEYS[1], slot, '1') == 1 then
  if inline then
    redis.call('SET', KEYS[9], inline)
  else
    redis.call('RENAME', KEYS[8], KEYS[9])
    redis.call('PERSIST', KEYS[9])
  end
  redis.call('HSET', KEYS[4], slot, ARGV[8])
  redis.call('HINCRBY', KEYS[7], 'done', k)
  first = k
elseif open and redis.call('HEXISTS', KEYS[1], slot) == 1 then
  if redis.call('GET', KEYS[9]) == (inline or redis.call('GET', KEYS[8])) then eq = k else diff = k end
  drop_upload()
else
  drop_upload()
  local d = redis.call('HGET', KEYS[4], slot)
  if not d then
    stale = k
  elseif d == ARGV[8] then
    eq = k
  else
    diff = k
  end
end
if first > 0 then redis.call('HINCRBY', KEYS[5], 'first', first) end
if eq > 0 then redis.call('HINCRBY', KEYS[5], 'dup_equal', eq) end
if stale > 0 then redis.call('HINCRBY', KEYS[5], 'stale', stale) end
if diff > 0 then
  redis.call('HINCRBY', KEYS[5], 'dup_differ', diff)
  redis.call('HSET', KEYS[3], 'mismatch', slot)
  redis.call('RPUSH', KEYS[6], ARGV[5])
elseif first > 0 and redis.call('HLEN', KEYS[1]) == tonumber(ARGV[4]) then
  redis.call('RPUSH', KEYS[6], ARGV[5])
end
return {first, eq, diff, stale}
)lua";

// An entry threw: count the failed delivery (against its first slot); below the
// limit, ack it and re-queue its blocks at once (another worker may take them); at
// the limit, mark the job failed with the worker's error. Returns 0 stale (or the
// entry is no longer pending), 1
// re-queued, 2 job failed.
// KEYS: stream, job, failures, counters, notify, wake
// ARGV: entry id, first slot, run, max failures, message, blocks, job id
inline constexpr std::string_view kFailScript = R"lua(
local run = redis.call('HGET', KEYS[2], 'run')
if run ~= ARGV[3] or redis.call('HGET', KEYS[2], 'cancelled') == '1' or redis.call('EXISTS', KEYS[1]) == 0 then
  return 0
end
-- Count a failure only while its entry is pending: a retry after a lost reply, or a
-- stalled worker failing an entry another one already finished, counts nothing.
if #redis.call('XPENDING', KEYS[1], 'w', ARGV[1], ARGV[1], 1) == 0 then
  return 0
end
redis.call('HINCRBY', KEYS[4], 'failures', 1)
local n = redis.call('HINCRBY', KEYS[3], ARGV[2], 1)
redis.call('XACK', KEYS[1], 'w', ARGV[1])
if n >= tonumber(ARGV[4]) then
  redis.call('HSET', KEYS[2], 'failed', ARGV[5])
  redis.call('RPUSH', KEYS[5], ARGV[7])
  return 2
end
redis.call('XADD', KEYS[1], '*', 'b', ARGV[6], 's', ARGV[2])
redis.call('XADD', KEYS[6], 'MAXLEN', '~', '1000', '*', 'j', ARGV[7])
return 1
)lua";

// A worker's lease heartbeat: resets the idle time of an entry this consumer still holds
// (never steals one that was reclaimed by another worker meanwhile). 1 kept, 0 not held.
// KEYS: stream   ARGV: entry id, consumer
inline constexpr std::string_view kKeepLeaseScript = R"lua(
local p = redis.call('XPENDING', KEYS[1], 'w', ARGV[1], ARGV[1], 1, ARGV[2])
if #p == 1 then
  redis.call('XCLAIM', KEYS[1], 'w', ARGV[2], 0, ARGV[1], 'JUSTID')
  return 1
end
return 0
)lua";

}  // namespace tally::cluster
