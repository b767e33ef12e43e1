#include "common/lighting/asset_resolver.hpp"

#include <fmt/format.h>

#include "common/lighting/scene_json.hpp"
#include "common/spec/spec_reader.hpp"

namespace tally {

std::filesystem::path resolve_scene_file(const std::string& name, const JobLimits& limits, const std::string& pointer) {
  if (!looks_like_asset_ref(name)) return resolve_asset(limits.asset_dir, name, pointer);
  const auto hex = asset_ref_hex(name);
  if (!hex) throw SpecError(pointer, "an asset reference must be \"sha256:\" and 64 lowercase hex digits");
  if (limits.asset_store.empty()) {
    throw SpecError(pointer, fmt::format("asset {} cannot be used: this runner has no asset store", name));
  }
  const std::filesystem::path p = stored_asset_path(limits.asset_store, *hex);
  std::error_code ec;
  if (!std::filesystem::is_regular_file(std::filesystem::symlink_status(p, ec))) {
    throw SpecError(pointer, fmt::format("asset {} is not stored on this server; upload it with PUT /v1/assets/{}",
                                         name, name));
  }
  return p;
}

std::string read_scene_file(const std::string& name, const JobLimits& limits, const std::string& pointer,
                            size_t max_bytes) {
  return read_asset_file(resolve_scene_file(name, limits, pointer), pointer, max_bytes);
}

}  // namespace tally
