#include "server/cluster/cluster_monitor.hpp"

#include <fmt/format.h>

#include <algorithm>

namespace tally::cluster {

namespace {
double unix_seconds() {
  return std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
}
}  // namespace

double ClusterMonitor::worker_timeout_s() const {
  return std::max(10.0, 3.0 * static_cast<double>(lease_.count()) / 1000.0);
}

bool ClusterMonitor::live(const WorkerRecord& w, double now) const { return now - w.last_heartbeat <= worker_timeout_s(); }

void ClusterMonitor::refresh(RedisConn& conn) {
  const double now = unix_seconds();
  const double timeout = worker_timeout_s();
  std::vector<WorkerRecord> ws = read_worker_registry(conn, now - 10 * timeout);
  std::erase_if(ws, [&](const WorkerRecord& w) { return now - w.last_heartbeat > timeout; });
  const std::optional<StoreCounters> c = read_store_counters(conn);
  const RedisMemory mem = read_memory(conn);
  std::lock_guard lock(mu_);
  workers_ = std::move(ws);
  memory_ = mem;
  if (mem.max > 0 && mem.used >= mem.max) oom_at_ = std::chrono::steady_clock::now();
  if (c) {
    counters_.first = c->first;
    counters_.dup_equal = c->dup_equal;
    counters_.dup_differ = c->dup_differ;
    counters_.stale = c->stale;
    counters_.failures = c->failures;
  }
}

std::vector<WorkerRecord> ClusterMonitor::workers() const {
  std::lock_guard lock(mu_);
  return workers_;
}

unsigned ClusterMonitor::live_threads() const {
  std::lock_guard lock(mu_);
  unsigned t = 0;
  for (const auto& w : workers_) t += w.threads;
  return t;
}

bool ClusterMonitor::any_live(const std::string& pool) const {
  const double now = unix_seconds();
  std::lock_guard lock(mu_);
  return std::any_of(workers_.begin(), workers_.end(), [&](const WorkerRecord& w) {
    return live(w, now) && (pool.empty() || std::find(w.pools.begin(), w.pools.end(), pool) != w.pools.end());
  });
}

std::optional<std::string> ClusterMonitor::waiting_for_workers(const std::string& pool) const {
  if (!any_live()) return std::string("waiting for a tally-worker: none is connected to Redis");
  if (!pool.empty() && !any_live(pool)) {
    return fmt::format("waiting for a tally-worker in pool \"{}\": none of the live workers serves it", pool);
  }
  return std::nullopt;
}

std::map<std::string, unsigned> ClusterMonitor::live_workers_by_pool() const {
  const double now = unix_seconds();
  std::lock_guard lock(mu_);
  std::map<std::string, unsigned> by_pool;
  for (const auto& w : workers_) {
    if (!live(w, now)) continue;
    for (const auto& p : w.pools) by_pool[p]++;
  }
  return by_pool;
}

void ClusterMonitor::count_live(unsigned& threads, unsigned& busy) const {
  const double now = unix_seconds();
  std::lock_guard lock(mu_);
  threads = busy = 0;
  for (const auto& w : workers_) {
    if (!live(w, now)) continue;
    threads += w.threads;
    if (!w.current_job.empty()) busy += 1;
  }
}

bool ClusterMonitor::note_redis_error(std::string_view error) {
  if (error.find("OOM ") == std::string_view::npos) return false;
  std::lock_guard lock(mu_);
  oom_at_ = std::chrono::steady_clock::now();
  oom_error_ = std::string(error);
  return true;
}

std::optional<std::string> ClusterMonitor::redis_problem() const {
  std::lock_guard lock(mu_);
  const bool full = memory_.max > 0 && memory_.used >= memory_.max;
  // An OOM error counts for 2 s: the next refresh (every 0.5 s) has seen the memory by then.
  const bool recent_error = !oom_error_.empty() && std::chrono::steady_clock::now() - oom_at_ < std::chrono::seconds(2);
  if (!full && !recent_error) return std::nullopt;
  return fmt::format("redis at {} is out of memory (used_memory {} of maxmemory {} bytes{}): workers cannot store "
                     "results and passes cannot be published; raise maxmemory or free memory (docs/cluster.md)",
                     redis_display_, memory_.used, memory_.max, full ? "" : fmt::format("; {}", oom_error_));
}

bool ClusterMonitor::out_of_memory_within(std::chrono::milliseconds window) const {
  std::lock_guard lock(mu_);
  return oom_at_ != std::chrono::steady_clock::time_point{} && std::chrono::steady_clock::now() - oom_at_ < window;
}

ClusterCounters ClusterMonitor::counters() const {
  std::lock_guard lock(mu_);
  return counters_;
}

void ClusterMonitor::count_merged(uint64_t blocks) {
  std::lock_guard lock(mu_);
  counters_.merged += blocks;
}

void ClusterMonitor::count_republished(uint64_t passes) {
  std::lock_guard lock(mu_);
  counters_.republished += passes;
}

void ClusterMonitor::count_ahead() {
  std::lock_guard lock(mu_);
  counters_.ahead++;
}

}  // namespace tally::cluster
