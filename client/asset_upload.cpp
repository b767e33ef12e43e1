#include "client/asset_upload.hpp"

#include <fmt/format.h>

#include "client/api_request.hpp"

namespace tally {

namespace fs = std::filesystem;

namespace {

// The server's asset store as a PackStore: HEAD, and PUT only what it lacks.
class HttpPackStore final : public PackStore {
 public:
  explicit HttpPackStore(HttpClient& client) : client_(client) {}

  void put_file(const std::string& ref, const fs::path& path) override {
    if (present(ref, path)) return;
    check(client_.send_file("PUT", "/v1/assets/" + ref, path.string()), path);
  }
  void put_bytes(const std::string& ref, const std::string& bytes, const fs::path& origin) override {
    if (present(ref, origin)) return;
    check(client_.request("PUT", "/v1/assets/" + ref, bytes, {{"Content-Type", "application/octet-stream"}}), origin);
  }

  AssetUploadReport report;

 private:
  bool present(const std::string& ref, const fs::path& path) {
    const ClientResponse head = client_.request("HEAD", "/v1/assets/" + ref);
    if (head.status == 200) {
      ++report.present;
      return true;
    }
    if (head.status == 404) return false;
    throw AssetRefused(fmt::format("asking the server whether it has {} failed: HTTP {}{}",
                                   path.lexically_normal().string(), head.status,
                                   head.status == 401 ? " (pass --token TOKEN or set TALLY_TOKEN)" : ""),
                       head.status);
  }
  void check(const ClientResponse& put, const fs::path& path) {
    if (put.status != 201 && put.status != 200) {
      throw AssetRefused(fmt::format("uploading {} failed: HTTP {}: {}", path.lexically_normal().string(), put.status,
                                     problem_detail(put)),
                         put.status);
    }
    ++report.uploaded;
  }

  HttpClient& client_;
};

}  // namespace

std::string AssetUploadReport::with_user_paths(std::string text) const {
  for (const auto& [ref, path] : origins) {
    for (size_t at = text.find(ref); at != std::string::npos; at = text.find(ref, at + path.size())) {
      text.replace(at, ref.size(), path);
    }
  }
  return text;
}

AssetUploadReport upload_scene_assets(HttpClient& client, nlohmann::json& spec, const fs::path& base_dir) {
  HttpPackStore store(client);
  ScenePacker packer(store, base_dir);
  packer.pack_spec(spec);
  store.report.origins = packer.origins();
  return store.report;
}

}  // namespace tally
