#include "server/cluster/cluster_http.hpp"

#include <fmt/format.h>

#include <chrono>
#include <ctime>

#include "server/http/prometheus.hpp"

namespace tally::cluster {

using nlohmann::json;

namespace {
json rfc3339(double t) {
  const auto secs = static_cast<std::time_t>(t);
  std::tm tm{};
  gmtime_r(&secs, &tm);
  return fmt::format("{:04}-{:02}-{:02}T{:02}:{:02}:{:02}Z", tm.tm_year + 1900, tm.tm_mon + 1, tm.tm_mday, tm.tm_hour,
                     tm.tm_min, tm.tm_sec);
}
}  // namespace

json workers_json(const RedisExecutor& ex) {
  const double now = std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
  json list = json::array();
  for (const WorkerRecord& w : ex.monitor().workers()) {
    list.push_back({{"name", w.name},
                    {"host", w.host},
                    {"threads", w.threads},
                    {"pools", w.pools},
                    {"last_heartbeat", rfc3339(w.last_heartbeat)},
                    {"seconds_since_heartbeat", std::max(0.0, now - w.last_heartbeat)},
                    {"blocks_done", w.blocks_done},
                    {"current_job", w.current_job.empty() ? json(nullptr) : json(w.current_job)}});
  }
  const ClusterCounters c = ex.monitor().counters();
  json j = {{"executor", "redis"},
            {"redis", ex.config().url.display()},
            {"lease_seconds", static_cast<double>(ex.config().lease.count()) / 1000.0},
            {"workers", list},
            {"pools", ex.monitor().live_workers_by_pool()},
            {"results", {{"first", c.first},
                         {"duplicates_equal", c.dup_equal},
                         {"duplicates_different", c.dup_differ},
                         {"stale", c.stale},
                         {"failed_deliveries", c.failures},
                         {"blocks_merged", c.merged},
                         {"passes_republished", c.republished},
                         {"passes_published_ahead", c.ahead}}}};
  if (auto why = ex.not_ready_reason()) j["not_ready_reason"] = *why;
  return j;
}

std::string cluster_metrics(const RedisExecutor& ex) {
  std::string o;
  const auto workers = ex.monitor().workers();
  unsigned threads = 0;
  for (const auto& w : workers) threads += w.threads;
  prom_metric(o, "tally_cluster_workers", "gauge", "Live tally-worker processes.", workers.size());
  prom_metric(o, "tally_cluster_worker_threads", "gauge", "Compute threads of the live workers.", threads);
  prom_header(o, "tally_cluster_pool_workers", "gauge",
              "Live tally-worker processes per worker pool they serve (--pool); a worker counts in each of its pools.");
  // Pools that jobs wait for and no live worker serves read 0 (a scaling signal).
  std::map<std::string, unsigned> by_pool = ex.monitor().live_workers_by_pool();
  for (const std::string& pool : ex.job_pools()) by_pool.try_emplace(pool, 0);
  for (const auto& [pool, n] : by_pool) {
    o += fmt::format("tally_cluster_pool_workers{{pool=\"{}\"}} {}\n", pool, n);
  }
  prom_header(o, "tally_cluster_worker_blocks_done", "counter", "Blocks computed, per worker.");
  for (const auto& w : workers) {
    o += fmt::format("tally_cluster_worker_blocks_done{{worker=\"{}\"}} {}\n", w.name, w.blocks_done);
  }
  prom_metric(o, "tally_cluster_redis_up", "gauge", "1 when the coordinator reaches Redis.",
              ex.redis_reachable() ? 1 : 0);
  prom_metric(o, "tally_cluster_redis_out_of_memory", "gauge",
              "1 while Redis refuses the cluster's writes (used_memory >= maxmemory, or an OOM reply).",
              ex.monitor().redis_problem() ? 1 : 0);
  const ClusterCounters c = ex.monitor().counters();
  prom_header(o, "tally_cluster_results_total", "counter", "Block results stored in Redis, by outcome.");
  o += fmt::format("tally_cluster_results_total{{outcome=\"first\"}} {}\n", c.first);
  o += fmt::format("tally_cluster_results_total{{outcome=\"duplicate_equal\"}} {}\n", c.dup_equal);
  o += fmt::format("tally_cluster_results_total{{outcome=\"duplicate_different\"}} {}\n", c.dup_differ);
  o += fmt::format("tally_cluster_results_total{{outcome=\"stale\"}} {}\n", c.stale);
  o += fmt::format("tally_cluster_results_total{{outcome=\"failed\"}} {}\n", c.failures);
  prom_metric(o, "tally_cluster_blocks_merged_total", "counter", "Blocks merged by this coordinator.", c.merged);
  prom_metric(o, "tally_cluster_passes_ahead_total", "counter",
              "Passes published before the pass before them was merged.", c.ahead);
  // Summed over the running jobs: no tenant's job id in a document the metrics role
  // (or anyone on loopback) reads. A job's own counts are in its status.
  ExecutorStats::JobBlocks all;
  for (const auto& [id, b] : ex.stats().blocks_by_job) {
    all.pending += b.pending;
    all.in_flight += b.in_flight;
    all.redelivered += b.redelivered;
  }
  prom_header(o, "tally_cluster_blocks", "gauge", "Blocks of the running jobs' current passes, by state.");
  o += fmt::format("tally_cluster_blocks{{state=\"pending\"}} {}\n", all.pending);
  o += fmt::format("tally_cluster_blocks{{state=\"in_flight\"}} {}\n", all.in_flight);
  o += fmt::format("tally_cluster_blocks{{state=\"redelivered\"}} {}\n", all.redelivered);
  return o;
}

}  // namespace tally::cluster
