#include "server/assets/asset_retention.hpp"

#include "common/log/log.hpp"
#include "server/assets/asset_refs.hpp"
#include "server/jobs/job_manager.hpp"

namespace tally {

RetentionResult sweep_unreferenced_assets(AssetStore& store, const JobManager& manager, std::chrono::seconds min_age) {
  std::set<std::string> referenced;
  for (const auto& job : manager.list()) {
    for (const AssetRef& a : asset_refs(job->spec())) referenced.insert(a.hex);
  }
  const RetentionResult r = store.sweep(referenced, min_age);
  log::info("asset retention: {} removed ({} bytes), {} kept ({} named by jobs)", r.removed, r.removed_bytes, r.kept,
            referenced.size());
  return r;
}

AssetRetention::AssetRetention(AssetStore& store, const JobManager& manager, double days) {
  if (!(days >= 0)) return;
  const auto min_age = std::chrono::seconds(static_cast<long long>(days * 86400.0));
  thread_ = std::thread([this, &store, &manager, min_age] {
    std::unique_lock lock(mu_);
    while (!stop_) {
      lock.unlock();
      try {
        sweep_unreferenced_assets(store, manager, min_age);
      } catch (const std::exception& e) {
        log::warn("asset retention: the sweep failed: {}", e.what());
      }
      lock.lock();
      cv_.wait_for(lock, std::chrono::hours(1), [this] { return stop_; });
    }
  });
}

void AssetRetention::stop() {
  {
    std::lock_guard lock(mu_);
    stop_ = true;
  }
  cv_.notify_all();
  if (thread_.joinable()) thread_.join();
}

}  // namespace tally
