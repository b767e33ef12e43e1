#pragma once
// Who is calling: a principal from the auth file (name, role, per-principal quotas),
// or the anonymous admin when access control is off.
#include <cstdint>
#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace tally {

// admin: everything. user: submit and act on its own jobs. reader: read-only on its
// own jobs. metrics: GET /metrics only (a Prometheus scraper).
enum class Role { admin, user, reader, metrics };

std::string_view role_name(Role r);
std::optional<Role> parse_role(std::string_view s);

struct Quotas {
  static constexpr uint64_t kUnlimited = std::numeric_limits<uint64_t>::max();
  uint64_t max_running_jobs = kUnlimited;  // this principal's jobs computing at once (more wait)
  uint64_t max_queued_jobs = kUnlimited;   // ... waiting for a slot (then 403)
  // Per-job caps, applied on top of (never above) the server's own.
  uint64_t max_samples = kUnlimited;
  double max_seconds = std::numeric_limits<double>::infinity();
  uint64_t max_pixels = kUnlimited;
  // Bytes of assets (PUT /v1/assets/...) this principal may have stored at once.
  uint64_t max_asset_bytes = kUnlimited;
  // Token bucket: sustained requests per second and burst size (0 = no limit).
  double requests_per_second = 0;
  double burst = 0;
};

class Revocation;

struct Principal {
  std::string name;  // "" = anonymous (access control off)
  Role role = Role::admin;
  Quotas quotas;
  // Worker pools its jobs may name (the spec's "pool"); empty: any pool, or none.
  std::vector<std::string> pools;
  bool via_cookie = false;  // authenticated by a browser session cookie
  // Set when revoked (token removed or changed, session logged out): streams opened
  // by this principal end. Null when access control is off.
  std::shared_ptr<Revocation> principal_revocation;
  std::shared_ptr<Revocation> session_revocation;

  bool is_admin() const { return role == Role::admin; }
  // May this principal see (and, role permitting, act on) a job owned by `owner`?
  bool may_see(std::string_view owner) const { return is_admin() || owner == name; }
};

}  // namespace tally
