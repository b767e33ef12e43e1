#include "server/assets/asset_refs.hpp"

#include <fmt/format.h>

#include <fstream>
#include <stdexcept>

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

std::vector<std::string> asset_refs_in_file(const std::filesystem::path& file) {
  std::ifstream in(file, std::ios::binary);
  if (!in) throw std::runtime_error(fmt::format("cannot read {}", file.string()));
  constexpr size_t kRef = kAssetRefPrefix.size() + 64;
  std::vector<std::string> out;
  std::string window;  // the last kRef - 1 bytes of the previous part, then the next part
  std::vector<char> part(size_t{1} << 20);
  while (in) {
    in.read(part.data(), static_cast<std::streamsize>(part.size()));
    window.append(part.data(), static_cast<size_t>(in.gcount()));
    for (size_t at = window.find(kAssetRefPrefix); at != std::string::npos && at + kRef <= window.size();
         at = window.find(kAssetRefPrefix, at + 1)) {
      if (auto hex = asset_ref_hex(std::string_view(window).substr(at, kRef))) out.push_back(*hex);
    }
    if (window.size() >= kRef) window.erase(0, window.size() - (kRef - 1));
  }
  if (in.bad()) throw std::runtime_error(fmt::format("cannot read {}", file.string()));
  return out;
}

std::vector<AssetRef> asset_refs(const nlohmann::json& spec) {
  std::vector<AssetRef> out;
  walk(spec, "", out);
  return out;
}

}  // namespace tally
