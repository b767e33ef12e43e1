#pragma once
// The cluster executor (coordinator side): each pass of a job becomes a Redis stream
// of its blocks with a consumer group; tally-worker processes (server/cluster/worker.hpp)
// compute them and store each result once, atomically (first wins, duplicates are
// compared byte for byte). This executor collects a complete pass, decodes it and
// hands it to pass_done in block order, so the bits equal an in-process run. It never
// computes blocks itself. Protocol: server/cluster/protocol.hpp, docs/cluster.md.
//
// Thread-safety: as Executor. One coordinator thread owns the Redis connection and
// runs every callback; add/cancel only queue requests for it.
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <deque>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "server/cluster/assets.hpp"
#include "server/cluster/redis_conn.hpp"
#include "server/executor/executor.hpp"

namespace tally::cluster {

struct RedisExecutorConfig {
  RedisUrl url;
  std::chrono::milliseconds lease{30000};  // a block's lease before workers reclaim it
  unsigned max_failures = 3;               // failed deliveries of one block that fail its job
  std::string asset_dir;                   // where the specs' OBJ files are read from
  std::string asset_store;                 // the server's asset store ("sha256:" names), JobLimits::asset_store
  size_t digest_passes = 16;               // passes whose result digests stay for late duplicates
  size_t max_entry_blocks = 4096;          // cap on blocks per stream entry (benchmarks set 1)
};

struct WorkerInfo {
  std::string name, host, current_job;
  unsigned threads = 0;
  double last_heartbeat = 0;  // unix seconds
  uint64_t blocks_done = 0;
};

// Cluster-wide result counts (since Redis started): what a test or operator checks to
// see that no block was merged twice and duplicates were compared.
struct ClusterCounters {
  uint64_t first = 0, dup_equal = 0, dup_differ = 0, stale = 0, failures = 0;
  uint64_t merged = 0;  // blocks merged by this coordinator
  uint64_t republished = 0;  // passes republished after Redis lost them
  uint64_t ahead = 0;        // passes published before the pass before them was merged (PassWork::ahead)
};

class RedisExecutor final : public Executor {
 public:
  RedisExecutor(RedisExecutorConfig config, ExecutorCallbacks callbacks);
  ~RedisExecutor() override;
  RedisExecutor(const RedisExecutor&) = delete;
  RedisExecutor& operator=(const RedisExecutor&) = delete;

  void add(ExecutorJob job, PassWork first_pass) override;
  bool cancel(const std::string& id) override;
  // Leaves Redis as it is (a restarted coordinator sweeps the old run's keys).
  void stop() override;
  ExecutorStats stats() const override;
  std::optional<std::string> not_ready_reason() const override;
  std::optional<std::string> waiting_reason(const std::string& id) const override;

  std::vector<WorkerInfo> workers() const;
  ClusterCounters counters() const;
  const RedisExecutorConfig& config() const { return cfg_; }

 private:
  // One pass of a job in Redis: the current one, or the next one published ahead of
  // it (PassWork::ahead) so workers never wait for the current pass's merge.
  struct PassRun {
    PassWork work;
    // The pass cut into stream entries: (first slot, blocks), in slot order. Planned at
    // its first publication and kept when it is published again, so a late result of an
    // entry from before a reconnect covers exactly the blocks of an entry published
    // after it (protocol.hpp).
    // Entries hold whole result groups (PassWork::groups): entry e's results are groups
    // [entry_groups[e], entry_groups[e + 1]), one combined result each.
    std::vector<std::pair<size_t, size_t>> entries;
    std::vector<size_t> entry_groups;
    size_t group_blocks = 1;  // the group size the groups were cut with (result_groups)
    size_t entry_blocks = 1;  // blocks in the largest entry
    // Results read and decoded so far, one per result group in order. They are read
    // while the pass runs, so the pass boundary reads only the last entries.
    std::vector<std::optional<BlockResult>> got;
    size_t got_count = 0;
    bool published = false;      // in Redis now
    bool was_published = false;  // published before (a republish)
    std::chrono::steady_clock::time_point start{};
    size_t bytes_read = 0;  // result bytes read so far
  };
  struct Job {
    ExecutorJob ej;
    std::string run;
    PassRun cur;
    std::unique_ptr<PassRun> ahead;  // the next pass, out before `cur` is merged
    std::map<std::string, JobAsset> assets;
    std::string manifest;
    bool swept = false;      // keys of older runs removed
    bool hash_written = false;  // the job hash (run, spec, assets) written for this run
    bool cancel_requested = false;
    std::deque<uint64_t> digest_passes;
    ExecutorStats::JobBlocks blocks;
    double block_seconds = 0;  // workers' measured compute time per block
    // Result bytes of the job's last merged pass (SIZE_MAX before the first): passes
    // with large results are read while they run (every 10 ms), others at the end.
    size_t last_pass_bytes = SIZE_MAX;
    bool all_published() const { return cur.published && (!ahead || ahead->published); }
  };

  void loop();
  void step();
  // The waker thread: on add/cancel it pushes kWakeMarker to the notify list the
  // coordinator blocks on (BLPOP cannot be interrupted otherwise), so a new job is
  // published at once, not when the wait times out. Its own connection.
  void wake_loop();
  void wake();
  bool connect();
  // Publishes the job's passes that are not in Redis (the current one, then the one ahead).
  void publish(Job& job);
  void publish_pass(Job& job, PassRun& pass);
  // Cuts a pass into stream entries of whole result groups (PassRun::entries).
  void plan_entries(const Job& job, PassRun& pass);
  // Deletes a pass's keys (stream, inputs, results, failures, digests).
  void delete_pass_keys(const Job& job, uint64_t pass);
  void sweep(const Job& job);
  // Checks the jobs' result hashes; merges complete passes. `ids` empty: all jobs.
  void poll(const std::vector<std::string>& ids);
  void merge(const std::string& id);
  // Reads the entries of the job's current pass not read yet into Job::got, decoded and
  // checked. `prefetch`: only the entries Redis lists now (while the pass runs); else
  // every missing one. Adds the bytes read to `bytes`. Returns an error that fails the
  // job (results that cannot be decoded or belong to other blocks), else "".
  std::string read_results(Job& job, PassRun& pass, bool prefetch, size_t& bytes);
  void prefetch();
  // The job with this id, or null (takes mu_ for the lookup only; a Job is erased only by
  // the coordinator thread, which is the caller).
  Job* find(const std::string& id) const;
  void leave(const std::string& id, bool failed, const std::string& error);
  void delete_job_keys(Job& job);
  // Deletes the keys of jobs that left the executor; one Redis could not reach stays
  // queued and is retried first thing in the next step (after a reconnect).
  void clean_finished();
  void refresh();

  RedisExecutorConfig cfg_;
  ExecutorCallbacks cb_;
  std::unique_ptr<RedisConn> conn_;  // coordinator thread only
  std::string run_id_;
  bool first_connect_ = true;
  uint64_t generation_ = 0;
  std::chrono::steady_clock::time_point last_poll_{}, last_refresh_{};
  std::chrono::steady_clock::time_point notified_at_{};  // the last BLPOP's return (latency lines)

  mutable std::mutex mu_;
  std::condition_variable cv_;
  std::map<std::string, std::unique_ptr<Job>> jobs_;
  std::deque<std::unique_ptr<Job>> finished_;  // coordinator thread only: keys still to delete
  std::optional<std::string> not_ready_;
  std::vector<WorkerInfo> workers_;
  ClusterCounters counters_;
  uint64_t samples_done_ = 0;
  bool stopping_ = false;
  bool wake_ = false;
  std::condition_variable wake_cv_;
  std::thread thread_, waker_;
};

}  // namespace tally::cluster
