#pragma once
// The retention rule of the asset store: an asset no job names (no job the manager
// knows, in any state: they are all in the job store), neither in its spec nor inside a
// scene file the job names (a glTF's buffers and images, an OBJ's .mtl and the .mtl's
// textures: asset_refs_in_file, followed to any depth), is removed once its last
// upload is older than --asset-retention-days. Runs on its own thread, at start and
// then hourly; every removal is logged. Negative days: never.
#include <condition_variable>
#include <mutex>
#include <thread>

#include "server/assets/asset_store.hpp"

namespace tally {

class JobManager;

// One sweep now: the hashes every job names, and those named inside them, then
// AssetStore::sweep. A named file that cannot be read skips the sweep (nothing removed).
RetentionResult sweep_unreferenced_assets(AssetStore& store, const JobManager& manager, std::chrono::seconds min_age);

class AssetRetention {
 public:
  AssetRetention(AssetStore& store, const JobManager& manager, double days);
  ~AssetRetention() { stop(); }
  void stop();

 private:
  std::mutex mu_;
  std::condition_variable cv_;
  bool stop_ = false;
  std::thread thread_;
};

}  // namespace tally
