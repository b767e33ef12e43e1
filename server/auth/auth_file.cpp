#include "server/auth/auth_file.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <fstream>
#include <set>
#include <sstream>

#include "common/spec/pool_field.hpp"
#include "common/spec/spec_reader.hpp"

namespace tally {

using nlohmann::json;

std::string_view role_name(Role r) {
  switch (r) {
    case Role::admin: return "admin";
    case Role::user: return "user";
    case Role::reader: return "reader";
    case Role::metrics: return "metrics";
  }
  return "unknown";
}

std::optional<Role> parse_role(std::string_view s) {
  for (Role r : {Role::admin, Role::user, Role::reader, Role::metrics}) {
    if (role_name(r) == s) return r;
  }
  return std::nullopt;
}

namespace {

bool is_lower_hex(std::string_view s) {
  for (char c : s) {
    if (!((c >= '0' && c <= '9') || (c >= 'a' && c <= 'f'))) return false;
  }
  return true;
}

bool is_name(std::string_view s) {
  if (s.empty() || s.size() > 64) return false;
  for (char c : s) {
    const bool ok = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '-' ||
                    c == '_' || c == '.' || c == '@';
    if (!ok) return false;
  }
  return true;
}

Quotas parse_quotas(SpecReader rd) {
  constexpr uint64_t kMax = Quotas::kUnlimited;
  Quotas q;
  q.max_running_jobs = rd.integer_or("max_running_jobs", kMax, 1, kMax);
  q.max_queued_jobs = rd.integer_or("max_queued_jobs", kMax, 0, kMax);
  q.max_samples = rd.integer_or("max_samples", kMax, 1, kMax);
  q.max_seconds = rd.number_or("max_seconds", q.max_seconds, 1e-3, 1e12);
  q.max_pixels = rd.integer_or("max_pixels", kMax, 1, kMax);
  q.max_asset_bytes = rd.integer_or("max_asset_bytes", kMax, 0, kMax);
  q.requests_per_second = rd.number_or("requests_per_second", 0.0, 1e-3, 1e9);
  q.burst = rd.number_or("burst", 0.0, 1.0, 1e9);
  rd.finish();
  if (q.requests_per_second > 0 && q.burst <= 0) q.burst = std::max(1.0, 2 * q.requests_per_second);
  if (q.burst > 0 && q.requests_per_second <= 0) {
    throw SpecError(rd.pointer_of("burst"), "burst needs requests_per_second");
  }
  return q;
}

// "pools": a non-empty array of distinct pool names.
std::vector<std::string> parse_pools(SpecReader& rd) {
  const json& list = rd.at("pools");
  const std::string at = rd.pointer_of("pools");
  if (!list.is_array() || list.empty()) throw SpecError(at, "must be a non-empty array of worker pool names");
  std::vector<std::string> pools;
  for (size_t i = 0; i < list.size(); ++i) {
    const std::string p = json_pointer_append(at, i);
    if (!list[i].is_string()) throw SpecError(p, "must be a string");
    const std::string name = list[i].get<std::string>();
    if (std::string why = pool_name_problem(name); !why.empty()) {
      throw SpecError(p, fmt::format("a worker pool's name {}, got \"{}\"", why, name));
    }
    if (std::find(pools.begin(), pools.end(), name) != pools.end()) {
      throw SpecError(p, fmt::format("pool \"{}\" is listed twice", name));
    }
    pools.push_back(name);
  }
  return pools;
}

}  // namespace

AuthFile parse_auth_file(const json& j) {
  SpecReader root(j, "");
  const json& list = root.at("principals");
  if (!list.is_array()) throw SpecError("/principals", "must be an array of principals");
  root.finish();
  AuthFile f;
  std::set<std::string> names, hashes;
  for (size_t i = 0; i < list.size(); ++i) {
    SpecReader rd(list[i], json_pointer_append("/principals", i));
    PrincipalEntry e;
    e.name = rd.string("name", 64);
    if (!is_name(e.name)) {
      throw SpecError(rd.pointer_of("name"), "a name is 1-64 characters of letters, digits and - _ . @");
    }
    e.role = *parse_role(rd.enumeration("role", {"admin", "user", "reader", "metrics"}));
    e.token_sha256 = rd.string("token_sha256", 64);
    if (e.token_sha256.size() != 64 || !is_lower_hex(e.token_sha256)) {
      throw SpecError(rd.pointer_of("token_sha256"),
                      "must be the token's SHA-256 as 64 lower-case hex digits (tally-server token new prints it)");
    }
    if (rd.has("quotas")) e.quotas = parse_quotas(rd.object("quotas"));
    if (rd.has("pools")) e.pools = parse_pools(rd);
    rd.finish();
    if (!names.insert(e.name).second) throw SpecError(rd.pointer_of("name"), fmt::format("duplicate name \"{}\"", e.name));
    if (!hashes.insert(e.token_sha256).second) {
      throw SpecError(rd.pointer_of("token_sha256"), "the same token is listed twice");
    }
    f.principals.push_back(std::move(e));
  }
  return f;
}

AuthFile load_auth_file(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw std::runtime_error(fmt::format("cannot read the auth file {}", path));
  std::stringstream ss;
  ss << in.rdbuf();
  json j;
  try {
    j = json::parse(ss.str());
  } catch (const json::parse_error& e) {
    throw std::runtime_error(fmt::format("auth file {}: malformed JSON: {}", path, e.what()));
  }
  try {
    return parse_auth_file(j);
  } catch (const SpecError& e) {
    throw std::runtime_error(fmt::format("auth file {}: {}", path, e.what()));
  }
}

json principal_entry_json(const PrincipalEntry& e) {
  json j = {{"name", e.name}, {"role", std::string(role_name(e.role))}, {"token_sha256", e.token_sha256}};
  json q = json::object();
  const Quotas d;
  if (e.quotas.max_running_jobs != d.max_running_jobs) q["max_running_jobs"] = e.quotas.max_running_jobs;
  if (e.quotas.max_queued_jobs != d.max_queued_jobs) q["max_queued_jobs"] = e.quotas.max_queued_jobs;
  if (e.quotas.max_asset_bytes != d.max_asset_bytes) q["max_asset_bytes"] = e.quotas.max_asset_bytes;
  if (e.quotas.requests_per_second > 0) {
    q["requests_per_second"] = e.quotas.requests_per_second;
    q["burst"] = e.quotas.burst;
  }
  if (!q.empty()) j["quotas"] = q;
  if (!e.pools.empty()) j["pools"] = e.pools;
  return j;
}

}  // namespace tally
