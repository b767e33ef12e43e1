#pragma once
// The "sha256:<hex>" references of a job spec: every string value of that form,
// wherever it is (a scene names assets in several fields: OBJ meshes, glTF, textures,
// environment maps). Used by the submit check (per-tenant visibility), retention
// (what jobs still name, also inside the scene files they name) and cluster mode (what
// to ship to workers).
#include <filesystem>
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

// The hashes a stored scene file names inside itself: every "sha256:<64 lowercase hex>"
// in its bytes (a glTF's buffer and image URIs, a .glb's JSON chunk, an OBJ's mtllib,
// an .mtl's texture maps), and every JSON string of a glTF (.gltf or a .glb's JSON chunk)
// that is one once unescaped and URI-decoded as the glTF loader does ("sha256\u003a…",
// "sha256%3A…"); read in parts, so any file size is fine. A superset of what
// the scene readers resolve (a binary buffer that happens to hold such text names more);
// retention keeps what they name. Throws std::runtime_error if the file cannot be read.
std::vector<std::string> asset_refs_in_file(const std::filesystem::path& file);

}  // namespace tally
