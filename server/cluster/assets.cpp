#include "server/cluster/assets.hpp"

#include <fmt/format.h>
#include <openssl/evp.h>
#include <unistd.h>

#include <fstream>
#include <sstream>

#include "common/lighting/asset_resolver.hpp"
#include "common/lighting/scene_json.hpp"
#include "server/cluster/protocol.hpp"
#include "server/cluster/redis_conn.hpp"

namespace tally::cluster {

namespace fs = std::filesystem;
using nlohmann::json;

std::string sha256_hex(std::string_view bytes) {
  unsigned char md[EVP_MAX_MD_SIZE];
  unsigned int len = 0;
  EVP_Digest(bytes.data(), bytes.size(), md, &len, EVP_sha256(), nullptr);
  std::string out;
  out.reserve(len * 2);
  for (unsigned i = 0; i < len; ++i) out += fmt::format("{:02x}", md[i]);
  return out;
}

namespace {

std::string read_file(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  if (!in) throw std::runtime_error(fmt::format("cannot read asset {}", p.string()));
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

void walk(const json& j, const std::string& pointer, const JobLimits& limits, std::map<std::string, JobAsset>& out) {
  if (j.is_string()) {
    const std::string& name = j.get_ref<const std::string&>();
    if (!looks_like_asset_ref(name) || out.count(name)) return;
    JobAsset a;
    a.bytes = read_scene_file(name, limits, pointer);  // same rule as the compiler
    a.sha256 = sha256_hex(a.bytes);
    out.emplace(name, std::move(a));
  } else if (j.is_object()) {
    for (const auto& [k, v] : j.items()) {
      const std::string p = pointer + "/" + k;
      if (is_scene_file_field(k) && v.is_string() && !looks_like_asset_ref(v.get<std::string>())) {
        const std::string rel = v.get<std::string>();
        if (out.count(rel)) continue;
        JobAsset a;
        a.bytes = read_file(resolve_scene_file(rel, limits, p));
        a.sha256 = sha256_hex(a.bytes);
        out.emplace(rel, std::move(a));
      } else {
        walk(v, p, limits, out);
      }
    }
  } else if (j.is_array()) {
    for (size_t i = 0; i < j.size(); ++i) walk(j[i], pointer + "/" + std::to_string(i), limits, out);
  }
}

bool is_hex64(const std::string& s) {
  if (s.size() != 64) return false;
  for (char c : s) {
    if (!((c >= '0' && c <= '9') || (c >= 'a' && c <= 'f'))) return false;
  }
  return true;
}

// A manifest path must stay inside the job directory: relative, no "..", no empty or
// "." components (the worker writes it before the compiler sees it).
bool safe_relative(const std::string& rel) {
  if (rel.empty() || rel.size() > 1024 || rel.front() == '/') return false;
  const fs::path p(rel);
  for (const auto& part : p) {
    const std::string s = part.string();
    if (s.empty() || s == "." || s == "..") return false;
  }
  return rel.find('\0') == std::string::npos;
}

}  // namespace

std::map<std::string, JobAsset> collect_assets(const json& spec, const std::string& asset_dir,
                                               const std::string& asset_store) {
  std::map<std::string, JobAsset> out;
  JobLimits limits;
  limits.asset_dir = asset_dir;
  limits.asset_store = asset_store;
  walk(spec, "", limits, out);
  return out;
}

json asset_manifest(const std::map<std::string, JobAsset>& assets) {
  json m = json::object();
  for (const auto& [rel, a] : assets) m[rel] = a.sha256;
  return m;
}

fs::path materialize_assets(RedisConn& conn, const json& manifest, const fs::path& cache_dir, const std::string& tag) {
  const fs::path blobs = cache_dir / "blobs";
  const fs::path dir = cache_dir / "jobs" / tag;
  fs::create_directories(blobs);
  fs::create_directories(dir);
  if (!manifest.is_object()) throw std::runtime_error("the job's asset manifest is not an object");
  for (const auto& [rel, v] : manifest.items()) {
    if (!v.is_string() || !is_hex64(v.get<std::string>()) || !safe_relative(rel)) {
      throw std::runtime_error(fmt::format("asset manifest entry \"{}\" is invalid", rel));
    }
    const std::string sha = v.get<std::string>();
    const fs::path blob = blobs / sha;
    if (!fs::exists(blob)) {
      const RValue r = conn.cmd({"GET", asset_key(sha)});
      if (r.is_nil()) throw std::runtime_error(fmt::format("asset {} ({}) is missing from Redis", rel, sha));
      if (sha256_hex(r.str) != sha) throw std::runtime_error(fmt::format("asset {} does not match its hash {}", rel, sha));
      const fs::path tmp = blobs / (sha + ".tmp" + std::to_string(::getpid()) + "_" +
                                    std::to_string(reinterpret_cast<uintptr_t>(&r)));
      {
        std::ofstream out(tmp, std::ios::binary);
        out.write(r.str.data(), static_cast<std::streamsize>(r.str.size()));
        if (!out) throw std::runtime_error(fmt::format("cannot write the asset cache {}", tmp.string()));
      }
      fs::rename(tmp, blob);
    }
    if (looks_like_asset_ref(rel)) continue;  // found by hash in cache_dir/blobs (JobLimits::asset_store)
    const fs::path target = dir / rel;
    fs::create_directories(target.parent_path());
    std::error_code ec;
    fs::remove(target, ec);
    fs::create_hard_link(blob, target, ec);
    if (ec) fs::copy_file(blob, target, fs::copy_options::overwrite_existing);
  }
  return dir;
}

}  // namespace tally::cluster
