#pragma once
// `tally submit`'s asset step: the local files a scene names (in the fields of
// is_scene_file_field: "obj", "map", "file" (glTF), ...) are uploaded to the server's asset store,
// only those it lacks (HEAD first), and the spec is rewritten to name them
// "sha256:<hex>". A name that is not a local file is left alone (the server may have
// it in its --asset-dir).
#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>

#include "client/http_client.hpp"

namespace tally {

struct AssetUploadReport {
  size_t uploaded = 0;  // PUT: the server lacked them
  size_t present = 0;   // HEAD said the server has them
};

// SHA-256 of a file, lowercase hex, read in pieces.
std::string sha256_file_hex(const std::filesystem::path& path);

// Relative names are taken relative to `base_dir` (the spec file's directory).
// Throws std::runtime_error (a failed upload names the file and the server's answer).
AssetUploadReport upload_scene_assets(HttpClient& client, nlohmann::json& spec, const std::filesystem::path& base_dir);

}  // namespace tally
