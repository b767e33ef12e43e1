#pragma once
// A job as the coordinator (RedisExecutor) holds it: its current run, the passes it has
// out in Redis (the current one and one published ahead), what was read of them, and
// the digests kept for late duplicates; and how it moves to its next pass. Owned and
// mutated by the coordinator thread (under the executor's lock where other threads read).
#include <chrono>
#include <cstdint>
#include <deque>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "server/cluster/assets.hpp"
#include "server/cluster/pass_entries.hpp"
#include "server/cluster/redis_conn.hpp"
#include "server/cluster/redis_layout.hpp"
#include "server/executor/executor.hpp"

namespace tally::cluster {

// One pass of a job in Redis: the current one, or the next one published ahead of it
// (PassWork::ahead) so workers never wait for the current pass's merge.
struct ClusterPassRun {
  PassWork work;
  EntryPlan plan;  // planned at its first publication, kept when published again
  // Results read and decoded so far, one per result group in order. They are read
  // while the pass runs, so the pass boundary reads only the last entries.
  std::vector<std::optional<BlockResult>> got;
  size_t got_count = 0;
  // A streamed job (ExecutorJob::stream_groups): groups [0, delivered) were read and
  // handed to the manager (group_done) in order; their `got` slots are empty again and
  // their entries are never read twice.
  size_t delivered = 0;
  bool published = false;      // in Redis now
  bool was_published = false;  // published before (a republish)
  std::chrono::steady_clock::time_point start{};
  size_t bytes_read = 0;  // result bytes read so far
};

struct ClusterJob {
  ExecutorJob ej;
  std::string run;
  ClusterPassRun cur;
  std::unique_ptr<ClusterPassRun> ahead;  // the next pass, out before `cur` is merged
  std::map<std::string, JobAsset> assets;
  std::string manifest;
  std::string pool;    // the worker pool it needs ("" = any)
  std::string active;  // the active set its streams go into (its pool's, redis_layout.hpp)
  bool swept = false;         // keys of older runs removed
  bool hash_written = false;  // the job hash (run, spec, assets) written for this run
  bool cancel_requested = false;
  std::deque<uint64_t> digest_passes;
  ExecutorStats::JobBlocks blocks;
  double block_seconds = 0;  // workers' measured compute time per block
  // Result bytes of the job's last merged pass (SIZE_MAX before the first): passes
  // with large results are read while they run (every 10 ms), others at the end.
  size_t last_pass_bytes = SIZE_MAX;

  bool all_published() const { return cur.published && (!ahead || ahead->published); }
  // Every pass it has out in Redis, and the passes whose digests are kept.
  std::vector<PassKeys> passes_out() const;
  std::vector<PassKeys> digest_keys() const;
  // The current pass was merged: its digests are kept (`keep` passes at most); returns
  // the keys of the digests to delete now.
  std::vector<PassKeys> retire_current(size_t keep);

  // Reads the entries of `pass` (cur or *ahead) not read yet into its `got`, decoded
  // and checked (digest under `key`, check_entry_digest; shape and counts,
  // decode_entry). `prefetch`: only the entries Redis lists now (while the pass runs);
  // else every missing one. Adds the bytes read to `bytes`. Returns an error that
  // fails the job, else "".
  std::string read_results(RedisConn& conn, ClusterPassRun& pass, bool prefetch, size_t& bytes, std::string_view key);

  // Moves on to `next`, the pass the job manager planned after the current one: the
  // pass published ahead is adopted if it is the same plan (its results so far
  // stand); otherwise it is dropped and, if there was one, the job continues as a new
  // run `new_run()` (what was computed for it must never be taken for the new plan's
  // blocks of the same pass number; the old run's keys are swept).
  enum class Advance { fresh, adopted, restarted };
  template <class NewRun>
  Advance advance(PassWork next, NewRun&& new_run);
};

template <class NewRun>
ClusterJob::Advance ClusterJob::advance(PassWork next, NewRun&& new_run) {
  std::shared_ptr<const PassWork> after = std::move(next.ahead);
  Advance how = Advance::fresh;
  if (ahead && same_plan(ahead->work, next)) {
    how = Advance::adopted;
    cur = std::move(*ahead);
    ahead.reset();
    cur.start = std::chrono::steady_clock::now();  // its wall time starts when the pass before it ends
  } else {
    if (ahead) how = Advance::restarted;
    ahead.reset();
    cur = ClusterPassRun{};
    cur.work = std::move(next);
    if (how == Advance::restarted) {
      run = new_run();
      swept = hash_written = false;
      digest_passes.clear();
    }
  }
  if (after) {
    ahead = std::make_unique<ClusterPassRun>();
    ahead->work = *after;
  }
  blocks = {};
  blocks.pending = cur.work.blocks.size();
  return how;
}

}  // namespace tally::cluster
