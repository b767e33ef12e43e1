#pragma once
// What the coordinator knows of the cluster beyond its jobs: the worker registry (who is
// live, with how many threads, in which pools) and the result counts. Refreshed from
// Redis by the coordinator thread (refresh), read by any thread (GET /v1/workers,
// /metrics, a job's waiting reason, the entry planner). Thread-safe.
#include <chrono>
#include <cstdint>
#include <map>
#include <mutex>
#include <string>
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
  explicit ClusterMonitor(std::chrono::milliseconds lease) : lease_(lease) {}

  // Reads the registry (forgetting entries silent for ten worker timeouts) and the
  // result counts. Coordinator thread; throws as the store does.
  void refresh(RedisConn& conn);

  // Seconds without a heartbeat after which a worker is not live (3 leases, >= 10 s).
  double worker_timeout_s() const;
  // Workers live at the last refresh.
  std::vector<WorkerRecord> workers() const;
  // Threads of the workers live now (at least the last refresh's heartbeats).
  unsigned live_threads() const;
  // Whether a worker is live now; with `pool`, one started with --pool pool.
  bool any_live(const std::string& pool = {}) const;
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
  mutable std::mutex mu_;
  std::vector<WorkerRecord> workers_;
  ClusterCounters counters_;
};

}  // namespace tally::cluster
