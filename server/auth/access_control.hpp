#pragma once
// Who may call: the principals of the --auth-file (reloaded on SIGHUP), browser
// sessions, and each principal's request rate. Knows nothing about routes; the one
// authorize step (server/auth/authorize.hpp) uses it. Thread-safety: every member
// may be called from any thread.
#include <chrono>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>

#include "server/auth/auth_file.hpp"
#include "server/auth/login_limiter.hpp"
#include "server/auth/principal.hpp"
#include "server/auth/revocation.hpp"
#include "server/auth/token_bucket.hpp"

namespace tally {

struct ReloadResult {
  size_t principals = 0;
  size_t added = 0;
  size_t revoked = 0;  // removed, or changed role/name: their streams and sessions end
};

class AccessControl {
 public:
  explicit AccessControl(AuthFile file);

  // Replaces the principals. Entries kept (same token, name and role) keep their
  // streams and sessions (quotas may change); the others are revoked.
  ReloadResult reload(AuthFile file);

  // The principal holding this bearer token, or nullopt (constant-time over every
  // stored hash, so timing does not tell how close a guess was).
  std::optional<Principal> authenticate_token(std::string_view token) const;
  std::optional<Principal> authenticate_session(std::string_view session_id);

  // A new browser session for `p` (from a bearer token); returns its id. A principal
  // holds at most kMaxSessionsPerPrincipal: beyond, its own oldest session ends. When
  // all principals together hold kMaxSessions, the oldest session of the principal
  // holding the most ends: one caller's logins never end another's session.
  std::string open_session(const Principal& p, double lifetime_s = 12 * 3600.0);
  static constexpr size_t kMaxSessions = 10000;
  static constexpr size_t kMaxSessionsPerPrincipal = 64;
  size_t session_count() const;
  void close_session(std::string_view session_id);

  // 0: the request may proceed; else seconds to wait (Retry-After).
  double take_request(const Principal& p);
  // The login rate limits (login_limiter.hpp), 0 or seconds to wait: a login attempt
  // from `address` (before the token is checked), and one by `p` (after).
  double take_login_attempt(std::string_view address);
  double take_login(const Principal& p);

  size_t principal_count() const;
  // The running-jobs quota of the principal named `name` (the smallest, if several
  // tokens share the name); unlimited if none is (e.g. revoked since).
  uint64_t max_running_jobs_of(std::string_view name) const;

 private:
  struct Entry {
    PrincipalEntry entry;
    std::shared_ptr<Revocation> revocation = std::make_shared<Revocation>();
  };
  struct Session {
    std::string token_sha256;  // the principal it belongs to
    std::shared_ptr<Revocation> revocation = std::make_shared<Revocation>();
    std::chrono::steady_clock::time_point expires;
  };
  std::optional<Principal> principal_locked(const Entry& e) const;
  void drop_expired_sessions_locked();

  mutable std::mutex mu_;
  std::vector<Entry> entries_;
  std::map<std::string, Session, std::less<>> sessions_;  // keyed by the SHA-256 of the session id
  std::map<std::string, TokenBucket, std::less<>> buckets_;  // by principal name
  LoginLimiter logins_;
};

}  // namespace tally
