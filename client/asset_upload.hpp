#pragma once
// `tally submit`'s asset step: the scene packer (scene_packer.hpp) over HTTP. Every
// local file the scene names, and every file those name (glTF buffers and images, an
// OBJ's .mtl and its map_Kd textures), goes to the server's asset store, only what it
// lacks (HEAD /v1/assets/sha256:<hex> first, then PUT), and the references are rewritten
// to "sha256:<hex>". A spec name that is not a local file is left alone (the server may
// have it in its --asset-dir).
#include <filesystem>
#include <map>
#include <nlohmann/json.hpp>
#include <stdexcept>
#include <string>

#include "client/http_client.hpp"
#include "client/scene_packer.hpp"

namespace tally {

// The server refused a HEAD or PUT of an asset; what() names the file and the answer.
class AssetRefused : public std::runtime_error {
 public:
  AssetRefused(const std::string& message, int http_status) : std::runtime_error(message), status(http_status) {}
  int status;
};

struct AssetUploadReport {
  size_t uploaded = 0;  // PUT: the server lacked them
  size_t present = 0;   // HEAD said the server has them
  // "sha256:<hex>" -> the user's path, to name files in the server's answers.
  std::map<std::string, std::string> origins;
  // `text` with every packed file's "sha256:<hex>" replaced by the user's path.
  std::string with_user_paths(std::string text) const;
};

// Relative names are taken relative to `base_dir` (the spec file's directory).
// Throws PackError (a file named in the scene that cannot be read, naming the user's
// path and the format) or AssetRefused (a refused HEAD or PUT, naming the file and the
// server's answer).
AssetUploadReport upload_scene_assets(HttpClient& client, nlohmann::json& spec, const std::filesystem::path& base_dir);

}  // namespace tally
