#include "server/api/metrics.hpp"

#include "server/http/prometheus.hpp"
#include "server/host/host_facts.hpp"

#include <fmt/format.h>

#include <fstream>
#include <optional>
#include <sstream>

namespace tally {

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
  prom_header(o, "tally_jobs", "gauge", "Jobs by state.");
  for (const auto& [state, n] : jobs.jobs_by_state) o += fmt::format("tally_jobs{{state=\"{}\"}} {}\n", state, n);
  prom_metric(o, "tally_queue_depth", "gauge", "Jobs waiting for a running slot.", jobs.queue_depth);
  prom_metric(o, "tally_samples_per_second", "gauge", "Sum of the running jobs' throughput.", jobs.samples_per_second);
  prom_metric(o, "tally_samples_total", "counter", "Samples computed by the workers since start.", jobs.samples_total);
  prom_metric(o, "tally_result_groups_streamed_total", "counter",
              "Result groups merged one by one as the workers finished them (streamed passes) since start.",
              jobs.groups_streamed);
  prom_metric(o, "tally_workers", "gauge", "Worker threads.", jobs.workers);
  prom_metric(o, "tally_workers_busy", "gauge", "Workers running a chunk right now.", jobs.busy_workers);
  prom_metric(o, "tally_store_failures_total", "counter", "Failed saves to the job store (each is retried).",
              jobs.store_failures);
  prom_metric(o, "tally_store_ok", "gauge", "1 while the job store takes writes, 0 while its last save failed.",
              jobs.store_ok ? 1 : 0);
  prom_metric(o, "tally_memory_budget_bytes", "gauge", "Memory for jobs' state (--memory-budget; 0: none).",
              jobs.memory_budget);
  prom_metric(o, "tally_memory_used_bytes", "gauge",
              "State of the jobs holding it in memory (running, resumed, extended).", jobs.memory_used);
  prom_metric(o, "tally_finished_state_cache_bytes", "gauge",
              "Finished jobs' states read back for images and kept (LRU).", jobs.finished_cache_bytes);
  prom_metric(o, "tally_finished_state_loads_total", "counter", "Finished jobs' states read back from the store.",
              jobs.state_loads);
  prom_metric(o, "tally_jobs_deleted_total", "counter", "Finished jobs deleted (DELETE or retention) since start.",
              jobs.jobs_removed);
  o += "# HELP tally_predicted_cpu_seconds Predicted CPU-seconds of work left, from the jobs' own forecasts "
       "(running: ETA x workers / running jobs; queued: jobs that ran before, at their rate). The autoscaling "
       "signal (docs/cluster.md).\n# TYPE tally_predicted_cpu_seconds gauge\n";
  o += fmt::format("tally_predicted_cpu_seconds{{state=\"running\"}} {}\n", jobs.predicted_cpu_seconds_running);
  o += fmt::format("tally_predicted_cpu_seconds{{state=\"queued\"}} {}\n", jobs.predicted_cpu_seconds_queued);
  prom_metric(o, "tally_preemptions_total", "counter",
              "Running jobs paused at a pass boundary for a waiting job that goes first.", jobs.preemptions);
  prom_metric(o, "tally_result_cache_hits_total", "counter",
              "Submits answered from a finished job's stored result (same spec and seed).", jobs.result_cache_hits);
  prom_metric(o, "tally_result_cache_misses_total", "counter", "Submits that looked in the result cache and computed.",
              jobs.result_cache_misses);
  if (const auto rss = resident_bytes()) {
    prom_metric(o, "tally_process_resident_bytes", "gauge", "Resident memory of the server process (VmRSS).", *rss);
  }
  prom_metric(o, "tally_http_connections", "gauge", "Open connections.", connections.load());
  prom_metric(o, "tally_http_event_streams", "gauge", "Open streamed responses (event streams; EXR images being sent).", streams.load());
  prom_metric(o, "tally_http_rejected_connections_total", "counter", "Connections refused at the limit.",
              rejected_connections.load());
  prom_metric(o, "tally_http_timeouts_total", "counter", "Connections closed by a read/idle/write timeout.",
              timeouts.load());
  prom_metric(o, "tally_http_accept_errors_total", "counter",
              "Failed accepts (out of descriptors or memory), each followed by a 100 ms back-off.",
              accept_errors.load());

  std::lock_guard lock(mu_);
  prom_header(o, "tally_http_requests_total", "counter", "Requests by route, method and status.");
  for (const auto& [k, n] : requests_) {
    o += fmt::format("tally_http_requests_total{{route=\"{}\",method=\"{}\",status=\"{}\"}} {}\n", std::get<0>(k),
                     std::get<1>(k), std::get<2>(k), n);
  }
  prom_header(o, "tally_http_request_duration_seconds", "histogram",
              "Time to produce the response (headers, for streams).");
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
