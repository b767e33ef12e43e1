#include "server/cluster/assets.hpp"

#include <fmt/format.h>
#include <unistd.h>

#include <cstring>
#include <fstream>
#include <sstream>

#include "common/lighting/asset_resolver.hpp"
#include "common/lighting/scene_json.hpp"
#include "server/cluster/cluster_store.hpp"
#include "server/cluster/redis_conn.hpp"

namespace tally::cluster {

namespace fs = std::filesystem;
using nlohmann::json;

namespace {

std::string read_file(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  if (!in) throw std::runtime_error(fmt::format("cannot read asset {}", p.string()));
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

std::string directory_of(const std::string& name) {
  const auto slash = name.find_last_of('/');
  return slash == std::string::npos ? std::string() : name.substr(0, slash + 1);
}

// The lines of `text` that start with `keyword` (then a blank), without the keyword.
std::vector<std::string> keyword_lines(const std::string& text, std::string_view keyword) {
  std::vector<std::string> out;
  std::istringstream in(text);
  std::string line;
  while (std::getline(in, line)) {
    const size_t b = line.find_first_not_of(" \t");
    if (b == std::string::npos || line.compare(b, keyword.size(), keyword) != 0) continue;
    const size_t rest = b + keyword.size();
    if (rest >= line.size() || (line[rest] != ' ' && line[rest] != '\t')) continue;
    std::string tail = line.substr(rest);
    while (!tail.empty() && (tail.back() == '\r' || tail.back() == ' ' || tail.back() == '\t')) tail.pop_back();
    out.push_back(tail);
  }
  return out;
}

std::vector<std::string> words(const std::string& s) {
  std::vector<std::string> out;
  std::istringstream in(s);
  for (std::string w; in >> w;) out.push_back(w);
  return out;
}

// The files a scene file itself names, as the compiler's reader will ask for them: a
// glTF's buffer and image URIs (not data: URIs; relative to the glTF's directory, or
// "sha256:" references), an OBJ's mtllib files and their map_Kd textures (relative to the
// OBJ's directory). Unreadable or malformed files name nothing here: the compiler reports
// them (the server compiled the job at submit with the same files).
std::vector<std::string> named_by(const std::string& field, const std::string& name, const std::string& bytes,
                                  const JobLimits& limits, const std::string& pointer) {
  std::vector<std::string> out;
  const std::string dir = directory_of(name);
  auto add = [&](const std::string& ref) {
    if (ref.empty() || ref.rfind("data:", 0) == 0) return;
    out.push_back(looks_like_asset_ref(ref) ? ref : dir + ref);
  };
  if (field == "file") {
    std::string_view text = bytes;
    if (bytes.size() >= 20 && bytes.compare(0, 4, "glTF") == 0) {  // .glb: the JSON chunk
      uint32_t len = 0;
      std::memcpy(&len, bytes.data() + 12, 4);
      text = std::string_view(bytes).substr(20, len);
    }
    const json doc = json::parse(text, nullptr, false);
    if (!doc.is_object()) return out;
    for (const char* list : {"buffers", "images"}) {
      const auto it = doc.find(list);
      if (it == doc.end() || !it->is_array()) continue;
      for (const json& e : *it) {
        if (e.is_object() && e.contains("uri") && e["uri"].is_string()) add(e["uri"].get<std::string>());
      }
    }
  } else if (field == "obj") {
    for (const std::string& libs : keyword_lines(bytes, "mtllib")) {
      for (const std::string& lib : words(libs)) {
        const std::string mtl_name = dir + lib;
        out.push_back(mtl_name);
        std::string mtl;
        try {
          mtl = read_scene_file(mtl_name, limits, pointer);
        } catch (const std::exception&) {
          continue;
        }
        for (const std::string& map : keyword_lines(mtl, "map_Kd")) {
          const std::vector<std::string> w = words(map);  // options first, the file last
          if (!w.empty()) add(w.back());
        }
      }
    }
  }
  return out;
}

void add_file(const std::string& name, const std::string& pointer, const JobLimits& limits,
              std::map<std::string, JobAsset>& out) {
  if (out.count(name)) return;
  JobAsset a;
  try {
    a.bytes = read_scene_file(name, limits, pointer);
  } catch (const std::exception&) {
    return;  // the compiler names it
  }
  a.sha256 = sha256_hex(a.bytes);
  out.emplace(name, std::move(a));
}

void walk(const json& j, const std::string& pointer, const JobLimits& limits, std::map<std::string, JobAsset>& out) {
  if (j.is_string()) {
    const std::string& name = j.get_ref<const std::string&>();
    if (!looks_like_asset_ref(name) || out.count(name)) return;
    JobAsset a;
    a.bytes = read_scene_file(name, limits, pointer);  // same rule as the compiler
    a.sha256 = sha256_hex(a.bytes);
    const std::string field = pointer.substr(pointer.find_last_of('/') + 1);
    for (const std::string& dep : named_by(field, name, a.bytes, limits, pointer)) add_file(dep, pointer, limits, out);
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
        for (const std::string& dep : named_by(k, rel, a.bytes, limits, p)) add_file(dep, p, limits, out);
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
      const std::optional<std::string> r = read_asset(conn, sha);
      if (!r) throw std::runtime_error(fmt::format("asset {} ({}) is missing from Redis", rel, sha));
      if (sha256_hex(*r) != sha) throw std::runtime_error(fmt::format("asset {} does not match its hash {}", rel, sha));
      const fs::path tmp = blobs / (sha + ".tmp" + std::to_string(::getpid()) + "_" +
                                    std::to_string(reinterpret_cast<uintptr_t>(&r)));
      {
        std::ofstream out(tmp, std::ios::binary);
        out.write(r->data(), static_cast<std::streamsize>(r->size()));
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
