#pragma once
// What the transport counts about its connections; the application exposes them
// (GET /metrics: tally_http_connections, ..._streams, ..._timeouts_total, ...).
#include <atomic>
#include <cstdint>

namespace tally {

struct ConnectionCounters {
  std::atomic<int64_t> connections{0};
  std::atomic<int64_t> streams{0};
  std::atomic<uint64_t> rejected_connections{0};
  std::atomic<uint64_t> timeouts{0};
  std::atomic<uint64_t> accept_errors{0};
};

}  // namespace tally
