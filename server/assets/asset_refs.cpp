#include "server/assets/asset_refs.hpp"

#include "common/lighting/asset_resolver.hpp"
#include "common/spec/spec_reader.hpp"

namespace tally {

namespace {

void walk(const nlohmann::json& j, const std::string& pointer, std::vector<AssetRef>& out) {
  if (j.is_string()) {
    if (auto hex = asset_ref_hex(j.get_ref<const std::string&>())) out.push_back({pointer, *hex});
  } else if (j.is_object()) {
    for (const auto& [k, v] : j.items()) walk(v, json_pointer_append(pointer, k), out);
  } else if (j.is_array()) {
    for (size_t i = 0; i < j.size(); ++i) walk(j[i], json_pointer_append(pointer, i), out);
  }
}

}  // namespace

std::vector<AssetRef> asset_refs(const nlohmann::json& spec) {
  std::vector<AssetRef> out;
  walk(spec, "", out);
  return out;
}

}  // namespace tally
