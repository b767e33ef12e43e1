#include "server/auth/access_control.hpp"

#include <algorithm>

#include "server/auth/token.hpp"

namespace tally {

namespace {

double now_s() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}
}  // namespace

AccessControl::AccessControl(AuthFile file) { reload(std::move(file)); }

ReloadResult AccessControl::reload(AuthFile file) {
  std::vector<std::shared_ptr<Revocation>> to_revoke;
  ReloadResult r;
  {
    std::lock_guard lock(mu_);
    std::vector<Entry> next;
    for (auto& pe : file.principals) {
      Entry e;
      e.entry = std::move(pe);
      for (const Entry& old : entries_) {
        if (old.entry.token_sha256 == e.entry.token_sha256 && old.entry.name == e.entry.name &&
            old.entry.role == e.entry.role) {
          e.revocation = old.revocation;
        }
      }
      next.push_back(std::move(e));
    }
    for (const Entry& old : entries_) {
      bool kept = false;
      for (const Entry& e : next) kept = kept || e.revocation == old.revocation;
      if (!kept) to_revoke.push_back(old.revocation);
    }
    r.principals = next.size();
    r.revoked = to_revoke.size();
    r.added = next.size() - (entries_.size() - to_revoke.size());
    entries_ = std::move(next);
    // Sessions of revoked principals go with them.
    for (auto it = sessions_.begin(); it != sessions_.end();) {
      bool alive = false;
      for (const Entry& e : entries_) alive = alive || e.entry.token_sha256 == it->second.token_sha256;
      if (!alive) {
        to_revoke.push_back(it->second.revocation);
        it = sessions_.erase(it);
      } else {
        ++it;
      }
    }
    for (auto it = buckets_.begin(); it != buckets_.end();) {
      const Entry* e = nullptr;
      for (const Entry& x : entries_) {
        if (x.entry.name == it->first) e = &x;
      }
      if (!e || e->entry.quotas.requests_per_second <= 0) {
        it = buckets_.erase(it);
      } else {
        it->second.reconfigure(e->entry.quotas.requests_per_second, e->entry.quotas.burst);
        ++it;
      }
    }
  }
  for (auto& rv : to_revoke) rv->revoke();
  return r;
}

std::optional<Principal> AccessControl::principal_locked(const Entry& e) const {
  Principal p;
  p.name = e.entry.name;
  p.role = e.entry.role;
  p.quotas = e.entry.quotas;
  p.pools = e.entry.pools;
  p.principal_revocation = e.revocation;
  return p;
}

std::optional<Principal> AccessControl::authenticate_token(std::string_view token) const {
  const std::string h = token_sha256_hex(token);
  std::lock_guard lock(mu_);
  const Entry* found = nullptr;
  for (const Entry& e : entries_) {
    // No early exit: every stored hash is compared.
    if (constant_time_equal(h, e.entry.token_sha256)) found = &e;
  }
  if (!found) return std::nullopt;
  return principal_locked(*found);
}

std::optional<Principal> AccessControl::authenticate_session(std::string_view session_id) {
  const std::string h = token_sha256_hex(session_id);
  std::lock_guard lock(mu_);
  drop_expired_sessions_locked();
  auto it = sessions_.find(h);  // a map lookup on a hash of a 256-bit secret leaks nothing useful
  if (it == sessions_.end()) return std::nullopt;
  for (const Entry& e : entries_) {
    if (e.entry.token_sha256 == it->second.token_sha256) {
      auto p = principal_locked(e);
      p->via_cookie = true;
      p->session_revocation = it->second.revocation;
      return p;
    }
  }
  return std::nullopt;
}

void AccessControl::drop_expired_sessions_locked() {
  const auto now = std::chrono::steady_clock::now();
  for (auto it = sessions_.begin(); it != sessions_.end();) {
    if (it->second.expires <= now) {
      it->second.revocation->revoke();
      it = sessions_.erase(it);
    } else {
      ++it;
    }
  }
}

std::string AccessControl::open_session(const Principal& p, double lifetime_s) {
  const std::string id = generate_session_id();
  std::lock_guard lock(mu_);
  drop_expired_sessions_locked();
  Session s;
  for (const Entry& e : entries_) {
    if (e.entry.name == p.name) s.token_sha256 = e.entry.token_sha256;
  }
  // Bounded, and fair: the room is made by the caller itself when it holds its share,
  // else by whoever holds the most sessions (the session of theirs closest to expiry).
  std::map<std::string_view, size_t> held;
  for (const auto& [sid, x] : sessions_) ++held[x.token_sha256];
  std::string_view evict_from;
  if (held[s.token_sha256] >= kMaxSessionsPerPrincipal) {
    evict_from = s.token_sha256;
  } else if (sessions_.size() >= kMaxSessions) {
    size_t most = 0;
    for (const auto& [who, n] : held) {
      if (n > most) {
        most = n;
        evict_from = who;
      }
    }
  }
  if (!evict_from.empty()) {
    auto oldest = sessions_.end();
    for (auto it = sessions_.begin(); it != sessions_.end(); ++it) {
      if (it->second.token_sha256 != evict_from) continue;
      if (oldest == sessions_.end() || it->second.expires < oldest->second.expires) oldest = it;
    }
    oldest->second.revocation->revoke();
    sessions_.erase(oldest);
  }
  s.expires = std::chrono::steady_clock::now() +
              std::chrono::duration_cast<std::chrono::steady_clock::duration>(std::chrono::duration<double>(lifetime_s));
  sessions_.emplace(token_sha256_hex(id), std::move(s));
  return id;
}

void AccessControl::close_session(std::string_view session_id) {
  std::shared_ptr<Revocation> rv;
  {
    std::lock_guard lock(mu_);
    auto it = sessions_.find(token_sha256_hex(session_id));
    if (it == sessions_.end()) return;
    rv = it->second.revocation;
    sessions_.erase(it);
  }
  rv->revoke();
}

double AccessControl::take_request(const Principal& p) {
  if (p.quotas.requests_per_second <= 0) return 0.0;
  std::lock_guard lock(mu_);
  const double now = now_s();
  auto it = buckets_.find(p.name);
  if (it == buckets_.end()) {
    it = buckets_.emplace(p.name, TokenBucket(p.quotas.requests_per_second, p.quotas.burst, now)).first;
  }
  return it->second.take(now);
}

double AccessControl::take_login_attempt(std::string_view address) { return logins_.take_address(address, now_s()); }

double AccessControl::take_login(const Principal& p) { return logins_.take_principal(p.name, now_s()); }

size_t AccessControl::session_count() const {
  std::lock_guard lock(mu_);
  return sessions_.size();
}

uint64_t AccessControl::max_running_jobs_of(std::string_view name) const {
  std::lock_guard lock(mu_);
  uint64_t most = Quotas::kUnlimited;
  for (const Entry& e : entries_) {
    if (e.entry.name == name) most = std::min(most, e.entry.quotas.max_running_jobs);
  }
  return most;
}

size_t AccessControl::principal_count() const {
  std::lock_guard lock(mu_);
  return entries_.size();
}

}  // namespace tally
