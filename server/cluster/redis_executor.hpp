#pragma once
// The cluster executor (coordinator side): each pass of a job becomes a Redis stream
// of its blocks with a consumer group; tally-worker processes (server/cluster/worker.hpp)
// compute them and store each result once, atomically (first wins, duplicates are
// compared byte for byte). This executor collects a complete pass, decodes it and
// hands it to pass_done in block order, so the bits equal an in-process run. It never
// computes blocks itself. Redis layout and operations: redis_layout.hpp and
// cluster_store.hpp; the worker registry: ClusterMonitor; docs/cluster.md.
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
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "server/cluster/assets.hpp"
#include "server/cluster/cluster_job.hpp"
#include "server/cluster/cluster_monitor.hpp"
#include "server/cluster/coordinator_waker.hpp"
#include "server/cluster/pass_entries.hpp"
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
  std::string result_key;                  // --result-key-file's bytes ("" = unkeyed digests), result_key.hpp
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
  // Redis unreachable, or out of memory (ClusterMonitor::redis_problem).
  std::optional<std::string> not_ready_reason() const override;
  bool redis_reachable() const;
  std::optional<std::string> waiting_reason(const std::string& id) const override;
  // A job whose pool has no live worker reads as queued (its waiting reason names the pool).
  bool holds_queued(const std::string& id) const override;

  const ClusterMonitor& monitor() const { return monitor_; }
  // The pools the jobs in the executor need ("" = any left out).
  std::set<std::string> job_pools() const;
  const RedisExecutorConfig& config() const { return cfg_; }

 private:
  using PassRun = ClusterPassRun;
  using Job = ClusterJob;

  void loop();
  void step();
  bool connect();
  // Publishes the job's passes that are not in Redis (the current one, then the one ahead).
  void publish(Job& job);
  void publish_pass(Job& job, PassRun& pass);
  // Checks the jobs' result hashes; merges complete passes. `ids` empty: all jobs.
  void poll(const std::vector<std::string>& ids);
  void merge(const std::string& id);
  // A streamed job's current pass: its groups read so far, from the first not handed
  // back, go to the manager in order (group_done) and leave `got`.
  void deliver(Job& job);
  // The job's passes are streamed (its groups go through group_done).
  bool streams(const Job& job) const { return job.ej.stream_groups && static_cast<bool>(cb_.group_done); }
  void prefetch();
  // The job with this id, or null (takes mu_ for the lookup only; a Job is erased only by
  // the coordinator thread, which is the caller).
  Job* find(const std::string& id) const;
  // The pool of the job with this id ("" = any), or nullopt if it is not here.
  std::optional<std::string> pool_of(const std::string& id) const;
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
  ClusterMonitor monitor_;
  uint64_t samples_done_ = 0;
  uint64_t groups_streamed_ = 0;  // guarded by mu_: result groups handed back one by one (deliver)
  bool stopping_ = false;
  CoordinatorWaker waker_;  // add/cancel wake the coordinator's BLPOP
  std::thread thread_;
};

}  // namespace tally::cluster
