#include "server/auth/authorize.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <optional>
#include <cmath>

#include "server/auth/token.hpp"
#include "server/http/problem.hpp"

namespace tally {

namespace {

std::string lower(std::string_view s) {
  std::string out(s);
  for (char& c : out) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return out;
}

std::string_view trim(std::string_view s) {
  while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) s.remove_prefix(1);
  while (!s.empty() && (s.back() == ' ' || s.back() == '\t')) s.remove_suffix(1);
  return s;
}

[[noreturn]] void unauthorized(std::string detail, std::string_view error = {}) {
  HttpError e(401, std::move(detail));
  e.headers.emplace_back("WWW-Authenticate", error.empty() ? std::string("Bearer realm=\"tally\"")
                                                           : fmt::format("Bearer realm=\"tally\", error=\"{}\"", error));
  throw e;
}

[[noreturn]] void forbidden(std::string detail) { throw HttpError(403, std::move(detail)); }

bool is_state_changing(std::string_view method) { return method != "GET" && method != "HEAD" && method != "OPTIONS"; }

// "https://host:port" -> ("https", "host:port"); nullopt if not of that shape.
std::optional<std::pair<std::string, std::string>> split_origin(std::string_view origin) {
  const size_t p = origin.find("://");
  if (p == std::string_view::npos) return std::nullopt;
  std::string_view authority = origin.substr(p + 3);
  if (authority.empty() || authority.find('/') != std::string_view::npos) return std::nullopt;
  return std::make_pair(lower(origin.substr(0, p)), lower(authority));
}

void check_host(const HttpRequest& req, const AccessPolicy& policy) {
  if (!policy.check_host) return;
  const std::string_view host = req.header("host");
  if (host.empty()) return;  // HTTP/1.0 without Host: not a browser, so not DNS rebinding
  const std::string name = host_without_port(host);
  if (std::find(policy.allowed_hosts.begin(), policy.allowed_hosts.end(), name) == policy.allowed_hosts.end()) {
    forbidden(fmt::format("Host \"{}\" is not allowed (server without access control; add it with --allowed-host)",
                          name));
  }
}

// A browser sends Origin on cross-origin requests and on same-origin writes; it must
// name this very server (scheme and Host), or the page calling us is someone else's.
void check_origin(const HttpRequest& req, const AccessPolicy& policy, bool required) {
  const std::string_view origin = req.header("origin");
  if (origin.empty()) {
    if (required) forbidden("a cookie-authenticated request that changes state needs an Origin header");
    return;
  }
  const auto o = split_origin(origin);
  const std::string host = lower(req.header("host"));
  const std::string scheme = policy.tls ? "https" : "http";
  if (!o || o->first != scheme || o->second != host) {
    forbidden(fmt::format("Origin \"{}\" does not match this server ({}://{})", origin, scheme, host));
  }
}

}  // namespace

std::string host_without_port(std::string_view host) {
  host = trim(host);
  if (!host.empty() && host.front() == '[') {
    const size_t close = host.find(']');
    return lower(close == std::string_view::npos ? host : host.substr(0, close + 1));
  }
  const size_t colon = host.find(':');
  return lower(host.substr(0, colon));
}

std::string cookie_value(const HttpRequest& request, std::string_view name) {
  for (const auto& [k, v] : request.headers) {
    if (k != "cookie") continue;
    std::string_view rest = v;
    while (!rest.empty()) {
      const size_t semi = rest.find(';');
      std::string_view pair = trim(rest.substr(0, semi));
      rest = semi == std::string_view::npos ? std::string_view{} : rest.substr(semi + 1);
      const size_t eq = pair.find('=');
      if (eq != std::string_view::npos && trim(pair.substr(0, eq)) == name) return std::string(trim(pair.substr(eq + 1)));
    }
  }
  return {};
}

RouteAccess route_access(std::string_view method, std::string_view pattern) {
  if (pattern == "/metrics") return RouteAccess::metrics;
  if (pattern == "/v1/workers") return RouteAccess::workers;  // operators: it names every tenant's jobs
  if (pattern.substr(0, 4) != "/v1/") return RouteAccess::open;
  if (pattern == "/v1/session") return method == "POST" ? RouteAccess::login : RouteAccess::session;
  return is_state_changing(method) ? RouteAccess::write : RouteAccess::read;
}

Principal authorize(const HttpRequest& req, std::string_view pattern, const AccessPolicy& policy) {
  check_host(req, policy);
  const RouteAccess access = route_access(req.method, pattern);
  const bool open = access == RouteAccess::open || access == RouteAccess::login ||
                    (access == RouteAccess::metrics && policy.metrics_open);
  if (!policy.access) {
    check_origin(req, policy, false);
    return Principal{};  // the anonymous admin
  }
  if (open) {
    check_origin(req, policy, false);
    Principal anyone;
    anyone.role = Role::reader;
    return anyone;
  }
  // Authenticate: a bearer token, else (browsers) the session cookie.
  std::optional<Principal> who;
  const std::string_view authz = req.header("authorization");
  if (!authz.empty()) {
    const std::string_view v = trim(authz);
    if (v.size() < 7 || lower(v.substr(0, 7)) != "bearer " || !is_b64token(trim(v.substr(7)))) {
      unauthorized("malformed Authorization header: expected \"Bearer <token>\"", "invalid_request");
    }
    who = policy.access->authenticate_token(trim(v.substr(7)));
    if (!who) unauthorized("unknown or revoked token", "invalid_token");
  } else if (const std::string sid = cookie_value(req, kSessionCookie); !sid.empty()) {
    who = policy.access->authenticate_session(sid);
    if (!who) unauthorized("the session has ended; log in again", "invalid_token");
  } else {
    unauthorized("this route needs \"Authorization: Bearer <token>\"");
  }
  check_origin(req, policy, who->via_cookie && is_state_changing(req.method));
  if (const double wait = policy.access->take_request(*who); wait > 0) {
    HttpError e(429, fmt::format("request rate over the quota of {} per second (requests_per_second) for \"{}\"",
                                 who->quotas.requests_per_second, who->name));
    e.headers.emplace_back("Retry-After", std::to_string(static_cast<long>(std::ceil(wait))));
    throw e;
  }
  switch (access) {
    case RouteAccess::metrics:
      if (who->role != Role::admin && who->role != Role::metrics) {
        forbidden(fmt::format("role {} may not read /metrics (admin or metrics may)", role_name(who->role)));
      }
      break;
    case RouteAccess::workers:
      if (who->role != Role::admin && who->role != Role::metrics) {
        forbidden(fmt::format("role {} may not read /v1/workers (admin or metrics may)", role_name(who->role)));
      }
      break;
    case RouteAccess::read:
      if (who->role == Role::metrics) forbidden("role metrics may only read /metrics");
      break;
    case RouteAccess::write:
      if (who->role != Role::admin && who->role != Role::user) {
        forbidden(fmt::format("role {} is read-only", role_name(who->role)));
      }
      break;
    default: break;
  }
  return *who;
}

}  // namespace tally
