#pragma once
// Prometheus text exposition for GET /metrics: request counts and latency
// histograms by route, plus job gauges from the manager.
#include <optional>
#include <array>
#include <atomic>
#include <map>
#include <mutex>
#include <string>
#include <string_view>
#include <tuple>

#include "server/http/connection_counters.hpp"
#include "server/jobs/job_manager.hpp"

namespace tally {

// The connection counters are the transport's (server/http), rendered here.
class Metrics : public ConnectionCounters {
 public:
  static constexpr std::array<double, 12> kBuckets = {0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025,
                                                      0.05,   0.1,   0.25,   0.5,   1.0,  2.5};

  // `route` must come from a closed set (a route pattern or "unmatched"); the
  // method is reduced to one (method_label), so no client can add label values.
  void observe(const std::string& route, std::string_view method, int status, double seconds);
  // The method itself when HTTP defines it (RFC 9110 §9), else "other".
  static std::string_view method_label(std::string_view method);

  std::string render(const ManagerStats& jobs) const;

 private:
  struct Histogram {
    std::array<uint64_t, kBuckets.size()> counts{};
    uint64_t count = 0;
    double sum = 0;
  };
  mutable std::mutex mu_;
  std::map<std::tuple<std::string, std::string, int>, uint64_t> requests_;
  std::map<std::pair<std::string, std::string>, Histogram> latency_;
};

}  // namespace tally
