#pragma once
// Whether the job store is taking writes. Every failed save is counted; while the
// last save failed the server is not ready (/readyz 503 naming the cause) and
// refuses new jobs. Saves that failed are retried (see JobManager) until stored.
// Thread-safe.
#include <cstdint>
#include <mutex>
#include <optional>
#include <string>

namespace tally {

class StoreHealth {
 public:
  void failed(const std::string& what) {
    std::lock_guard lock(mu_);
    ++failures_;
    error_ = what;
  }
  void succeeded() {
    std::lock_guard lock(mu_);
    error_.reset();
  }
  // The cause while the store is failing, else nullopt.
  std::optional<std::string> problem() const {
    std::lock_guard lock(mu_);
    return error_;
  }
  uint64_t failures() const {
    std::lock_guard lock(mu_);
    return failures_;
  }

 private:
  mutable std::mutex mu_;
  uint64_t failures_ = 0;
  std::optional<std::string> error_;
};

}  // namespace tally
