#include "server/api/metrics.hpp"

#include <fmt/format.h>

namespace tally {

void Metrics::observe(const std::string& route, const std::string& method, int status, double seconds) {
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
