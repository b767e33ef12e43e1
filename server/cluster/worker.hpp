#pragma once
// tally-worker's engine: N compute threads, each with its own Redis connection, take
// blocks from the active pass streams (XREADGROUP), reclaim blocks whose lease expired
// (XAUTOCLAIM), compute them with the kernel compiled from the job's spec (with this
// worker's own limits and only the job's assets) and store each result with one Lua
// script (first wins, duplicates compared). A heartbeat thread keeps the leases of the
// blocks being computed (XCLAIM ... JUSTID) and the worker registry entry fresh.
// Stateless: killing it at any moment loses nothing but the blocks in flight, which
// other workers reclaim after the lease.
#include <atomic>
#include <filesystem>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "common/engine/job_definition.hpp"
#include "server/cluster/redis_conn.hpp"

namespace tally::cluster {

struct WorkerConfig {
  RedisUrl url;
  unsigned threads = 1;
  std::string name;  // unique per process; default host-pid
  std::string host;
  // Pools this worker serves (--pool): it takes jobs that need one of them, and jobs
  // without a pool. Empty: jobs without a pool only.
  std::vector<std::string> pools;
  JobLimits limits;  // re-validation of every spec read from Redis
  std::filesystem::path cache_dir;  // asset cache
  std::string health_file;          // touched at every heartbeat (liveness probes)
  std::string result_key;           // --result-key-file's bytes ("" = unkeyed), result_key.hpp
  bool verbose = false;
  // Tests only (tests/cluster's fault-injecting worker): wraps every compiled kernel.
  // Empty in tally-worker.
  std::function<std::shared_ptr<const Kernel>(std::shared_ptr<const Kernel>)> wrap_kernel;
};

// Runs until `stop` becomes true (checked at least every half second). Returns 0.
int run_worker(const WorkerConfig& config, const std::atomic<bool>& stop);

// tally-worker's command line (worker_cli.cpp): parses flags into a WorkerConfig, checks
// the credentials once (refused: exit code 2 with the reason; Redis merely unreachable:
// the worker starts and waits for it), runs until SIGTERM/SIGINT. `wrap_kernel` as in
// WorkerConfig.
int worker_main(int argc, char** argv,
                std::function<std::shared_ptr<const Kernel>(std::shared_ptr<const Kernel>)> wrap_kernel = {});

}  // namespace tally::cluster
