#pragma once
// Wakes the coordinator's BLPOP on tally:notify (which nothing else can interrupt) when a
// job is added or cancelled, so a new job is published at once, not when the wait times
// out. A thread with its own connection; wake() only sets a flag for it.
#include <condition_variable>
#include <mutex>
#include <thread>

#include "server/cluster/redis_conn.hpp"

namespace tally::cluster {

class CoordinatorWaker {
 public:
  explicit CoordinatorWaker(RedisUrl url);
  ~CoordinatorWaker();
  CoordinatorWaker(const CoordinatorWaker&) = delete;
  CoordinatorWaker& operator=(const CoordinatorWaker&) = delete;

  void wake();
  void stop();

 private:
  void loop();

  const RedisUrl url_;
  std::mutex mu_;
  std::condition_variable cv_;
  bool wake_ = false, stopping_ = false;
  std::thread thread_;
};

}  // namespace tally::cluster
