#include "server/api/metrics.hpp"

#include <fmt/format.h>

#include <fstream>
#include <optional>
#include <sstream>

namespace tally {

std::optional<uint64_t> resident_bytes() {
  std::ifstream in("/proc/self/status");
  for (std::string line; std::getline(in, line);) {
    if (line.rfind("VmRSS:", 0) == 0) {
      std::istringstream f(line.substr(6));
      uint64_t kib = 0;
      if (f >> kib) return kib * 1024;
    }
  }
  return std::nullopt;
}

std::string_view Metrics::method_label(std::string_view method) {
  static constexpr std::array<std::string_view, 9> known = {"GET",     "HEAD",    "POST",  "PUT",  "DELETE",
                                                            "CONNECT", "OPTIONS", "TRACE", "PATCH"};
  for (std::string_view k : known) {
    if (method == k) return k;
  }
  return "other";
}

void Metrics::observe(const std::string& route, std::string_view raw_method, int status, double seconds) {
  const std::string method(method_label(raw_method));
  std::lock_guard lock(mu_);
  requests_[{route, method, status}]++;
  Histogram& h = latency_[{route, method}];
  for (size_t i = 0; i < kBuckets.size(); ++i) {
    if (seconds <= kBuckets[i]) h.counts[i]++;
  }
  h.count++;
  h.sum += seconds;
}

std::string Metrics::render(const ManagerStats& jobs) const {
  std::string o;
  o += "# HELP tally_jobs Jobs by state.\n# TYPE tally_jobs gauge\n";
  for (const auto& [state, n] : jobs.jobs_by_state) o += fmt::format("tally_jobs{{state=\"{}\"}} {}\n", state, n);
  o += "# HELP tally_queue_depth Jobs waiting for a running slot.\n# TYPE tally_queue_depth gauge\n";
  o += fmt::format("tally_queue_depth {}\n", jobs.queue_depth);
  o += "# HELP tally_samples_per_second Sum of the running jobs' throughput.\n# TYPE tally_samples_per_second gauge\n";
  o += fmt::format("tally_samples_per_second {}\n", jobs.samples_per_second);
  o += "# HELP tally_samples_total Samples computed by the workers since start.\n# TYPE tally_samples_total counter\n";
  o += fmt::format("tally_samples_total {}\n", jobs.samples_total);
  o += "# HELP tally_workers Worker threads.\n# TYPE tally_workers gauge\n";
  o += fmt::format("tally_workers {}\n", jobs.workers);
  o += "# HELP tally_workers_busy Workers running a chunk right now.\n# TYPE tally_workers_busy gauge\n";
  o += fmt::format("tally_workers_busy {}\n", jobs.busy_workers);
  o += "# HELP tally_store_failures_total Failed saves to the job store (each is retried).\n"
       "# TYPE tally_store_failures_total counter\n";
  o += fmt::format("tally_store_failures_total {}\n", jobs.store_failures);
  o += "# HELP tally_store_ok 1 while the job store takes writes, 0 while its last save failed.\n"
       "# TYPE tally_store_ok gauge\n";
  o += fmt::format("tally_store_ok {}\n", jobs.store_ok ? 1 : 0);
  o += "# HELP tally_memory_budget_bytes Memory for jobs' state (--memory-budget; 0: none).\n"
       "# TYPE tally_memory_budget_bytes gauge\n";
  o += fmt::format("tally_memory_budget_bytes {}\n", jobs.memory_budget);
  o += "# HELP tally_memory_used_bytes State of the jobs holding it in memory (running, resumed, extended).\n"
       "# TYPE tally_memory_used_bytes gauge\n";
  o += fmt::format("tally_memory_used_bytes {}\n", jobs.memory_used);
  o += "# HELP tally_finished_state_cache_bytes Finished jobs' states read back for images and kept (LRU).\n"
       "# TYPE tally_finished_state_cache_bytes gauge\n";
  o += fmt::format("tally_finished_state_cache_bytes {}\n", jobs.finished_cache_bytes);
  o += "# HELP tally_finished_state_loads_total Finished jobs' states read back from the store.\n"
       "# TYPE tally_finished_state_loads_total counter\n";
  o += fmt::format("tally_finished_state_loads_total {}\n", jobs.state_loads);
  o += "# HELP tally_jobs_deleted_total Finished jobs deleted (DELETE or retention) since start.\n"
       "# TYPE tally_jobs_deleted_total counter\n";
  o += fmt::format("tally_jobs_deleted_total {}\n", jobs.jobs_removed);
  if (const auto rss = resident_bytes()) {
    o += "# HELP tally_process_resident_bytes Resident memory of the server process (VmRSS).\n"
         "# TYPE tally_process_resident_bytes gauge\n";
    o += fmt::format("tally_process_resident_bytes {}\n", *rss);
  }
  o += "# HELP tally_http_connections Open connections.\n# TYPE tally_http_connections gauge\n";
  o += fmt::format("tally_http_connections {}\n", connections.load());
  o += "# HELP tally_http_event_streams Open event streams.\n# TYPE tally_http_event_streams gauge\n";
  o += fmt::format("tally_http_event_streams {}\n", streams.load());
  o += "# HELP tally_http_rejected_connections_total Connections refused at the limit.\n"
       "# TYPE tally_http_rejected_connections_total counter\n";
  o += fmt::format("tally_http_rejected_connections_total {}\n", rejected_connections.load());
  o += "# HELP tally_http_timeouts_total Connections closed by a read/idle/write timeout.\n"
       "# TYPE tally_http_timeouts_total counter\n";
  o += fmt::format("tally_http_timeouts_total {}\n", timeouts.load());
  o += "# HELP tally_http_accept_errors_total Failed accepts (out of descriptors or memory), each followed by a "
       "100 ms back-off.\n# TYPE tally_http_accept_errors_total counter\n";
  o += fmt::format("tally_http_accept_errors_total {}\n", accept_errors.load());

  std::lock_guard lock(mu_);
  o += "# HELP tally_http_requests_total Requests by route, method and status.\n# TYPE tally_http_requests_total counter\n";
  for (const auto& [k, n] : requests_) {
    o += fmt::format("tally_http_requests_total{{route=\"{}\",method=\"{}\",status=\"{}\"}} {}\n", std::get<0>(k),
                     std::get<1>(k), std::get<2>(k), n);
  }
  o += "# HELP tally_http_request_duration_seconds Time to produce the response (headers, for streams).\n"
       "# TYPE tally_http_request_duration_seconds histogram\n";
  for (const auto& [k, h] : latency_) {
    const std::string labels = fmt::format("route=\"{}\",method=\"{}\"", k.first, k.second);
    for (size_t i = 0; i < kBuckets.size(); ++i) {
      o += fmt::format("tally_http_request_duration_seconds_bucket{{{},le=\"{}\"}} {}\n", labels, kBuckets[i], h.counts[i]);
    }
    o += fmt::format("tally_http_request_duration_seconds_bucket{{{},le=\"+Inf\"}} {}\n", labels, h.count);
    o += fmt::format("tally_http_request_duration_seconds_sum{{{}}} {}\n", labels, h.sum);
    o += fmt::format("tally_http_request_duration_seconds_count{{{}}} {}\n", labels, h.count);
  }
  return o;
}

}  // namespace tally
