#include "server/assets/asset_retention.hpp"

#include "common/lighting/asset_resolver.hpp"
#include "common/log/log.hpp"
#include "server/assets/asset_refs.hpp"
#include "server/jobs/job_manager.hpp"

namespace tally {

RetentionResult sweep_unreferenced_assets(AssetStore& store, const JobManager& manager, std::chrono::seconds min_age) {
  std::set<std::string> referenced;
  std::vector<std::string> to_scan;  // named, not yet read for the names inside it
  auto name = [&](const std::string& hex) {
    if (referenced.insert(hex).second) to_scan.push_back(hex);
  };
  for (const auto& job : manager.list()) {
    for (const AssetRef& a : asset_refs(job->spec())) name(a.hex);
  }
  // What the named files name in turn (a glTF's .bin, an OBJ's .mtl and its textures).
  while (!to_scan.empty()) {
    const std::string hex = std::move(to_scan.back());
    to_scan.pop_back();
    const std::filesystem::path blob = stored_asset_path(store.blob_dir(), hex);
    std::error_code ec;
    if (!std::filesystem::exists(blob, ec)) continue;  // named but not stored
    try {
      for (const std::string& inner : asset_refs_in_file(blob)) name(inner);
    } catch (const std::exception& e) {
      // Unreadable now: what it names cannot be known, so nothing is removed this time.
      log::warn("asset retention: cannot read sha256:{} for the assets it names ({}); the sweep is skipped", hex,
                e.what());
      return RetentionResult{};
    }
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
