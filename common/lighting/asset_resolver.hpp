#pragma once
// The one place a scene's file names become files. A scene names a file in one of
// two ways, wherever it names one (an OBJ mesh, a glTF, a texture, an environment map):
//   "sha256:<64 lowercase hex>"  an asset in the content-addressed store
//                                (JobLimits::asset_store, filled by PUT /v1/assets/...);
//   "relative/path.obj"          a file inside JobLimits::asset_dir (--asset-dir).
// Every loader calls resolve_scene_file (and reads through read_scene_file or
// read_asset_file), so both kinds obey the same checks: no escape from either
// directory, no symlink or FIFO, a size cap, and a SpecError naming the field's
// JSON pointer (a missing stored asset is named by its hash).
#include <filesystem>
#include <functional>
#include <optional>
#include <string>
#include <string_view>

#include "common/engine/limits.hpp"

namespace tally {

inline constexpr std::string_view kAssetRefPrefix = "sha256:";

inline bool is_sha256_hex(std::string_view hex) {
  if (hex.size() != 64) return false;
  for (char c : hex) {
    if (!((c >= '0' && c <= '9') || (c >= 'a' && c <= 'f'))) return false;
  }
  return true;
}
// True when `name` is meant as a store reference (starts with "sha256:"), well-formed or not.
inline bool looks_like_asset_ref(std::string_view name) { return name.substr(0, kAssetRefPrefix.size()) == kAssetRefPrefix; }
// The 64 hex digits of a well-formed "sha256:<hex>" reference (lowercase), or nullopt.
inline std::optional<std::string> asset_ref_hex(std::string_view ref) {
  if (!looks_like_asset_ref(ref) || !is_sha256_hex(ref.substr(kAssetRefPrefix.size()))) return std::nullopt;
  return std::string(ref.substr(kAssetRefPrefix.size()));
}

// The scene fields whose string value names a file (a path or a "sha256:" reference).
// Loaders of new file kinds add their field here: the CLI uploads what these name and
// cluster mode ships it to workers. "file" is a glTF (gltf_scene.hpp); the files *it*
// names (external buffers) and an OBJ's .mtl libraries are read through the same
// resolver but are not uploaded or shipped: over the API use .glb, or name them by
// "sha256:" URIs inside the file.
inline bool is_scene_file_field(std::string_view key) { return key == "obj" || key == "map" || key == "file"; }

// The store's layout, shared by the server's AssetStore and the cluster worker's
// cache: one file per asset, named by its hash, directly in the store directory.
inline std::filesystem::path stored_asset_path(const std::filesystem::path& store, std::string_view hex) {
  return store / std::string(hex);
}

// Returns the bytes of the file `name` (a path inside the asset directory, or a
// "sha256:" reference); throws SpecError(pointer) when it may not or cannot be read.
using AssetReader = std::function<std::string(const std::string& name, const std::string& pointer)>;

// Resolves `relative` inside `asset_dir`: no absolute paths, no "..", and no symlink
// that leads outside. Throws SpecError(pointer) otherwise.
std::filesystem::path resolve_asset(const std::string& asset_dir, const std::string& relative,
                                    const std::string& pointer);

// The bytes of a file resolve_asset or resolve_scene_file returned: opened without
// following a symlink and without blocking, and only if it is a regular file of at most
// `max_bytes`.
std::string read_asset_file(const std::filesystem::path& path, const std::string& pointer,
                            size_t max_bytes = size_t{1} << 30);

// The file `name` (a scene field at `pointer`) stands for. Throws SpecError(pointer):
// a malformed reference, no store configured, an asset not stored ("asset sha256:…
// is not stored on this server; upload it with PUT /v1/assets/sha256:…"), or for a
// relative path whatever resolve_asset refuses.
std::filesystem::path resolve_scene_file(const std::string& name, const JobLimits& limits, const std::string& pointer);

// resolve_scene_file + read_asset_file (regular file only, no symlink, size cap).
std::string read_scene_file(const std::string& name, const JobLimits& limits, const std::string& pointer,
                            size_t max_bytes = size_t{1} << 30);

// The reader every file a scene names goes through (OBJ, .mtl, glTF and its buffers,
// textures, environment maps): read_scene_file with these limits.
AssetReader scene_asset_reader(const JobLimits& limits);

}  // namespace tally
