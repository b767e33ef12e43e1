#include "server/cluster/cluster_monitor.hpp"

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
  std::lock_guard lock(mu_);
  workers_ = std::move(ws);
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
