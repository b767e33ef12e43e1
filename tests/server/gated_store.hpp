#pragma once
// A test store that wraps another; a save of a row `hold` picks waits at a gate until
// the test opens it (a store that is slow at exactly the save under test).
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <functional>
#include <memory>
#include <mutex>

#include "server/jobs/job_store.hpp"

namespace tally::test {

class GatedStore final : public JobStore {
 public:
  GatedStore(std::unique_ptr<JobStore> inner, std::function<bool(const StoredJob&)> hold)
      : inner_(std::move(inner)), hold_(std::move(hold)) {}
  void save(const StoredJob& j) override {
    if (hold_(j)) {
      std::unique_lock lock(mu_);
      held_ = true;
      cv_.notify_all();
      cv_.wait(lock, [&] { return open_; });
    }
    inner_->save(j);
    saves_done_.fetch_add(1);
  }
  std::vector<StoredJob> load_all() override { return inner_->load_all(); }
  std::optional<std::string> load_checkpoint(const std::string& id) override { return inner_->load_checkpoint(id); }
  bool remove(const std::string& id) override { return inner_->remove(id); }
  uint64_t next_epoch() override { return inner_->next_epoch(); }
  bool wait_until_a_save_is_held(double seconds) {
    std::unique_lock lock(mu_);
    return cv_.wait_for(lock, std::chrono::duration<double>(seconds), [&] { return held_; });
  }
  void open() {
    std::lock_guard lock(mu_);
    open_ = true;
    cv_.notify_all();
  }
  std::atomic<int> saves_done_{0};

 private:
  std::unique_ptr<JobStore> inner_;
  std::function<bool(const StoredJob&)> hold_;
  std::mutex mu_;
  std::condition_variable cv_;
  bool held_ = false, open_ = false;
};

}  // namespace tally::test
