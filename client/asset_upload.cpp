#include "client/asset_upload.hpp"

#include <fmt/format.h>
#include <openssl/evp.h>

#include <fstream>
#include <map>
#include <memory>
#include <vector>

#include "client/api_request.hpp"
#include "common/lighting/asset_resolver.hpp"

namespace tally {

namespace fs = std::filesystem;

std::string sha256_file_hex(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error(fmt::format("cannot read {}", path.string()));
  std::unique_ptr<EVP_MD_CTX, decltype(&EVP_MD_CTX_free)> ctx(EVP_MD_CTX_new(), EVP_MD_CTX_free);
  if (!ctx || EVP_DigestInit_ex(ctx.get(), EVP_sha256(), nullptr) != 1) throw std::runtime_error("SHA-256 unavailable");
  std::vector<char> buf(1 << 20);
  while (in) {
    in.read(buf.data(), static_cast<std::streamsize>(buf.size()));
    EVP_DigestUpdate(ctx.get(), buf.data(), static_cast<size_t>(in.gcount()));
  }
  if (in.bad()) throw std::runtime_error(fmt::format("cannot read {}", path.string()));
  unsigned char md[EVP_MAX_MD_SIZE];
  unsigned int len = 0;
  EVP_DigestFinal_ex(ctx.get(), md, &len);
  std::string out;
  for (unsigned i = 0; i < len; ++i) out += fmt::format("{:02x}", md[i]);
  return out;
}

namespace {

struct Uploader {
  HttpClient& client;
  fs::path base;
  AssetUploadReport report;
  std::map<std::string, std::string> done;  // local path -> "sha256:<hex>"

  std::string upload(const fs::path& path) {
    const std::string key = fs::absolute(path).lexically_normal().string();
    if (auto it = done.find(key); it != done.end()) return it->second;
    const std::string ref = "sha256:" + sha256_file_hex(path);
    const std::string target = "/v1/assets/" + ref;
    const ClientResponse head = client.request("HEAD", target);
    if (head.status == 200) {
      ++report.present;
    } else if (head.status == 404) {
      const ClientResponse put = client.send_file("PUT", target, path.string());
      if (put.status != 201 && put.status != 200) {
        throw std::runtime_error(fmt::format("uploading {} failed: HTTP {}: {}", path.string(), put.status,
                                             problem_detail(put)));
      }
      ++report.uploaded;
    } else {
      throw std::runtime_error(fmt::format("asking the server for {} ({}) failed: HTTP {}", path.string(), ref,
                                           head.status));
    }
    done.emplace(key, ref);
    return ref;
  }

  void walk(nlohmann::json& j) {
    if (j.is_object()) {
      for (auto& [k, v] : j.items()) {
        if (is_scene_file_field(k) && v.is_string() && !looks_like_asset_ref(v.get<std::string>())) {
          const fs::path name(v.get<std::string>());
          const fs::path local = name.is_absolute() ? name : base / name;
          std::error_code ec;
          if (fs::is_regular_file(local, ec)) v = upload(local);
        } else {
          walk(v);
        }
      }
    } else if (j.is_array()) {
      for (auto& v : j) walk(v);
    }
  }
};

}  // namespace

AssetUploadReport upload_scene_assets(HttpClient& client, nlohmann::json& spec, const fs::path& base_dir) {
  Uploader u{client, base_dir, {}, {}};
  u.walk(spec);
  return u.report;
}

}  // namespace tally
