#include "server/cluster/coordinator_waker.hpp"

#include <fmt/format.h>

#include <memory>

#include "common/log/log.hpp"
#include "server/cluster/cluster_store.hpp"

namespace tally::cluster {

CoordinatorWaker::CoordinatorWaker(RedisUrl url) : url_(std::move(url)) { thread_ = std::thread([this] { loop(); }); }

CoordinatorWaker::~CoordinatorWaker() { stop(); }

void CoordinatorWaker::wake() {
  {
    std::lock_guard lock(mu_);
    wake_ = true;
  }
  cv_.notify_all();
}

void CoordinatorWaker::stop() {
  {
    std::lock_guard lock(mu_);
    stopping_ = true;
  }
  cv_.notify_all();
  if (thread_.joinable()) thread_.join();
}

void CoordinatorWaker::loop() {
  std::unique_ptr<RedisConn> conn;
  for (;;) {
    {
      std::unique_lock lock(mu_);
      cv_.wait(lock, [&] { return stopping_ || wake_; });
      if (stopping_) return;
      wake_ = false;
    }
    try {
      if (!conn) conn = std::make_unique<RedisConn>(url_, std::chrono::milliseconds(1000));
      push_wake_marker(*conn);
    } catch (const std::exception& e) {
      // Harmless: the coordinator's wait ends by its timeout (<= 50 ms) anyway.
      conn.reset();
      log::write(log::Level::debug, "", fmt::format("cluster waker: {}", e.what()));
    }
  }
}

}  // namespace tally::cluster
