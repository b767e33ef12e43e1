#pragma once
// Job assets without a shared file system. The coordinator finds the OBJ files a spec
// names (scene shapes' "obj"), reads them from its --asset-dir and stores their bytes in
// Redis under their SHA-256 (content-addressed, so a file shared by many jobs is stored
// once). The job's manifest maps each relative path to its hash. A worker fetches what
// it lacks into a local cache, checks the hash, and gives the compiler a per-job
// directory holding exactly those files: the worker's compiler, with its own limits,
// never reads anything else.
#include <filesystem>
#include <map>
#include <nlohmann/json.hpp>
#include <string>

#include "common/hash/digest.hpp"

namespace tally::cluster {

class RedisConn;

struct JobAsset {
  std::string sha256;  // lowercase hex
  std::string bytes;
};

using ::tally::sha256_hex;  // common/hash/digest.hpp

// name -> asset, for every file the spec names: a relative path in a file field ("obj",
// "map", "file") read from asset_dir, or a "sha256:<hex>" string anywhere, read from the
// asset store (both through resolve_scene_file, the compiler's own rule), and the files
// those name in turn: a glTF's external buffers and images, an OBJ's .mtl libraries and
// their map_Kd textures (each by the name the compiler will ask for; skipped when it
// cannot be read: the worker's compiler then names it). Throws (SpecError or
// std::runtime_error) when a file the spec names cannot be read.
std::map<std::string, JobAsset> collect_assets(const nlohmann::json& spec, const std::string& asset_dir,
                                               const std::string& asset_store = {});
// {"name": "sha256", ...}
nlohmann::json asset_manifest(const std::map<std::string, JobAsset>& assets);

// Worker side: fetches and verifies the blobs the manifest names that
// cache_dir/blobs/<sha> lacks (cache_dir/blobs has the asset store's layout: it is the
// worker's JobLimits::asset_store, for "sha256:" names), and links relative paths
// under cache_dir/jobs/<tag>/. Returns the directory to use as JobLimits::asset_dir.
// Throws std::runtime_error naming the bad entry.
std::filesystem::path materialize_assets(RedisConn& conn, const nlohmann::json& manifest,
                                         const std::filesystem::path& cache_dir, const std::string& tag);

}  // namespace tally::cluster
