#pragma once
// What the coordinator knows of the cluster beyond its jobs: the worker registry (who is
// live, with how many threads, in which pools) and the result counts. Refreshed from
// Redis by the coordinator thread (refresh), read by any thread (GET /v1/workers,
// /metrics, a job's waiting reason, the entry planner). Thread-safe.
#include <chrono>
#include <cstdint>
#include <map>
#include <optional>
#include <mutex>
#include <string>
#include <string_view>
#include <vector>

#include "server/cluster/cluster_store.hpp"

namespace tally::cluster {

// Cluster-wide result counts (since Redis started): what a test or operator checks to
// see that no block was merged twice and duplicates were compared.
struct ClusterCounters {
  uint64_t first = 0, dup_equal = 0, dup_differ = 0, stale = 0, failures = 0;
  uint64_t merged = 0;       // blocks merged by this coordinator
  uint64_t republished = 0;  // passes republished after Redis lost them
  uint64_t ahead = 0;        // passes published before the pass before them was merged (PassWork::ahead)
};

class ClusterMonitor {
 public:
  ClusterMonitor(std::chrono::milliseconds lease, std::string redis_display)
      : lease_(lease), redis_display_(std::move(redis_display)) {}

  // Reads the registry (forgetting entries silent for ten worker timeouts), the result
  // counts and Redis's memory. Coordinator thread; throws as the store does.
  void refresh(RedisConn& conn);

  // An error reply the coordinator got: an OOM one marks Redis out of memory for a
  // few seconds (until a refresh sees it has room again). Returns whether it was OOM.
  bool note_redis_error(std::string_view error);
  // Why Redis cannot take the cluster's writes now (out of memory), else nullopt.
  std::optional<std::string> redis_problem() const;
  // Whether Redis was out of memory within `window` (deliveries that failed meanwhile
  // are not a worker crashing on a block).
  bool out_of_memory_within(std::chrono::milliseconds window) const;

  // Seconds without a heartbeat after which a worker is not live (3 leases, >= 10 s).
  double worker_timeout_s() const;
  // Workers live at the last refresh.
  std::vector<WorkerRecord> workers() const;
  // Threads of the workers live now (at least the last refresh's heartbeats).
  unsigned live_threads() const;
  // Whether a worker is live now; with `pool`, one started with --pool pool.
  bool any_live(const std::string& pool = {}) const;
  // Why a job needing `pool` ("" = any) waits for workers: none is live, or none
  // serves its pool; nullopt when one can compute it.
  std::optional<std::string> waiting_for_workers(const std::string& pool) const;
  // Live workers per pool they serve (a worker counts in each of its pools).
  std::map<std::string, unsigned> live_workers_by_pool() const;
  // Workers with a current job, and their threads (ExecutorStats).
  void count_live(unsigned& threads, unsigned& busy) const;

  ClusterCounters counters() const;
  void count_merged(uint64_t blocks);
  void count_republished(uint64_t passes);
  void count_ahead();

 private:
  bool live(const WorkerRecord& w, double now) const;

  const std::chrono::milliseconds lease_;
  const std::string redis_display_;
  mutable std::mutex mu_;
  RedisMemory memory_;
  std::chrono::steady_clock::time_point oom_at_{};  // last OOM seen (error or INFO)
  std::string oom_error_;                           // its error reply, if one
  std::vector<WorkerRecord> workers_;
  ClusterCounters counters_;
};

}  // namespace tally::cluster
