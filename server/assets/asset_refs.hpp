#pragma once
// The "sha256:<hex>" references of a job spec: every string value of that form,
// wherever it is (a scene names assets in several fields: OBJ meshes, glTF, textures,
// environment maps). Used by the submit check (per-tenant visibility), retention
// (what jobs still name) and cluster mode (what to ship to workers).
#include <nlohmann/json.hpp>
#include <string>
#include <utility>
#include <vector>

namespace tally {

struct AssetRef {
  std::string pointer;  // JSON pointer of the string
  std::string hex;      // the 64 hex digits
};

// In document order; a string starting with "sha256:" that is not 64 lowercase hex
// digits is skipped here (the scene reader refuses it, naming its pointer).
std::vector<AssetRef> asset_refs(const nlohmann::json& spec);

}  // namespace tally
