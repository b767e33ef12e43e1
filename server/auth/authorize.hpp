#pragma once
// The one authorize step, run by the request handler before any route: Host
// allowlist (DNS rebinding), Origin check, authentication (bearer token or browser
// session cookie), the caller's request rate and its role's permission for the
// route. Yields the Principal or throws HttpError (400/401/403/429, problem+json).
// Which jobs a principal may see is Principal::may_see; the job routes apply it.
#include <string>
#include <string_view>
#include <vector>

#include "server/auth/access_control.hpp"
#include "server/auth/principal.hpp"
#include "server/http/http_types.hpp"

namespace tally {

struct AccessPolicy {
  AccessControl* access = nullptr;  // null: access control off, every caller is the anonymous admin
  bool metrics_open = true;         // GET /metrics without a token (loopback listeners)
  bool check_host = false;          // enforce allowed_hosts (on when access control is off)
  std::vector<std::string> allowed_hosts = {"127.0.0.1", "localhost", "[::1]"};  // lower case, no port
  bool tls = false;                 // the listener speaks HTTPS (cookies are Secure, Origin scheme https)
  bool insecure_no_auth = false;    // --insecure-no-auth: open off loopback (shown on /readyz, /metrics)
};

// How a route is guarded.
enum class RouteAccess {
  open,     // /livez, /readyz, static files: no credentials
  login,    // POST /v1/session: takes a token in its body
  metrics,  // GET /metrics: open on loopback, else admin or metrics role
  workers,  // GET /v1/workers: admin or metrics role (it names every tenant's jobs)
  read,     // GET on /v1: any role but metrics
  write,    // everything else on /v1: admin and user
  session,  // GET/DELETE /v1/session: any authenticated principal
};
RouteAccess route_access(std::string_view method, std::string_view pattern);

inline constexpr std::string_view kSessionCookie = "tally_session";

Principal authorize(const HttpRequest& request, std::string_view route_pattern, const AccessPolicy& policy);

// The value of cookie `name` in the request's Cookie header(s), "" if absent.
std::string cookie_value(const HttpRequest& request, std::string_view name);
// Host header without its port, lower case ("[::1]" keeps its brackets).
std::string host_without_port(std::string_view host);

}  // namespace tally
