#include "server/api/request_handler.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <chrono>
#include <cmath>

#include "common/spec/json_depth.hpp"
#include "common/spec/spec_reader.hpp"
#include "server/http/problem.hpp"
#include "server/http/prometheus.hpp"
#include "server/api/route_support.hpp"
#include "server/api/static_files.hpp"
#include "server/auth/token.hpp"

namespace tally {

using nlohmann::json;

RequestHandler::RequestHandler(JobManager& manager, Metrics& metrics, HandlerConfig config)
    : manager_(manager), metrics_(metrics), config_(std::move(config)) {
  add_routes();
}

void RequestHandler::add_routes() {
  using namespace std::placeholders;
  auto bind = [this](HttpResponse (RequestHandler::*fn)(const ApiRequest&, const PathParams&)) {
    return [this, fn](const ApiRequest& r, const PathParams& p) { return (this->*fn)(r, p); };
  };
  router_.add("GET", "/livez", [](const ApiRequest&, const PathParams&) {
    HttpResponse r;
    r.set_header("Content-Type", "text/plain; charset=utf-8");
    r.body = "ok\n";
    return r;
  });
  router_.add("GET", "/readyz", [this](const ApiRequest&, const PathParams&) {
    if (!ready_ || manager_.shutting_down()) throw HttpError(503, "the server is not ready (starting or shutting down)");
    if (auto why = manager_.not_ready_reason()) throw HttpError(503, "the server is not ready: " + *why);
    if (auto why = manager_.executor_not_ready()) throw HttpError(503, "the server is not ready: " + *why);
    HttpResponse r;
    r.set_header("Content-Type", "text/plain; charset=utf-8");
    r.body = config_.access.insecure_no_auth ? "ready (INSECURE: no access control, --insecure-no-auth)\n" : "ready\n";
    if (auto warning = manager_.ready_warning()) r.body += "warning: " + *warning + "\n";
    return r;
  });
  router_.add("GET", "/metrics", [this](const ApiRequest&, const PathParams&) {
    HttpResponse r;
    r.set_header("Content-Type", "text/plain; version=0.0.4; charset=utf-8");
    r.body = metrics_.render(manager_.stats());
    prom_metric(r.body, "tally_access_control", "gauge", "1 when bearer tokens are required (--auth-file)",
                config_.access.access ? 1 : 0);
    prom_metric(r.body, "tally_insecure_no_auth", "gauge",
                "1 when listening off loopback without access control (--insecure-no-auth)",
                config_.access.insecure_no_auth ? 1 : 0);
    if (config_.extra_metrics) r.body += config_.extra_metrics();
    return r;
  });
  router_.add("GET", "/v1/workers", [this](const ApiRequest&, const PathParams&) {
    HttpResponse r;
    r.set_header("Content-Type", "application/json");
    const json j = config_.workers ? config_.workers() : json{{"executor", "in_process"}, {"workers", json::array()}};
    r.body = j.dump();
    r.body.push_back('\n');
    return r;
  });
  router_.add("GET", "/v1/openapi.json", [](const ApiRequest&, const PathParams&) {
    HttpResponse r;
    r.set_header("Content-Type", "application/json");
    r.body = openapi_document();
    return r;
  });
  router_.add("POST", "/v1/jobs", bind(&RequestHandler::post_job), Lane::blocking);
  router_.add("GET", "/v1/jobs", bind(&RequestHandler::list_jobs));
  router_.add("POST", "/v1/jobs/validate", bind(&RequestHandler::validate_job), Lane::slow);
  router_.add("GET", "/v1/jobs/{id}", bind(&RequestHandler::get_job));
  // Deleting a finished job, and extending one, touch its stored state: off the I/O threads.
  router_.add("DELETE", "/v1/jobs/{id}", bind(&RequestHandler::delete_job), Lane::blocking);
  router_.add("POST", "/v1/jobs/{id}/extend", bind(&RequestHandler::extend_job), Lane::blocking);
  // A priority change is stored before it is acknowledged: off the I/O threads.
  router_.add("PATCH", "/v1/jobs/{id}", bind(&RequestHandler::patch_job), Lane::blocking);
  router_.add("GET", "/v1/jobs/{id}/events", bind(&RequestHandler::job_events));
  // May read a finished job's state from the store: off the I/O threads.
  router_.add("GET", "/v1/jobs/{id}/tiles/{n}", bind(&RequestHandler::job_tile), Lane::blocking);
  router_.add("GET", "/v1/jobs/{id}/image.exr",
              [this](const ApiRequest& r, const PathParams& p) { return job_image(r, p, true); }, Lane::blocking);
  router_.add("GET", "/v1/jobs/{id}/image.png",
              [this](const ApiRequest& r, const PathParams& p) { return job_image(r, p, false); }, Lane::blocking);
  router_.add("POST", "/v1/session", bind(&RequestHandler::login));
  router_.add("GET", "/v1/session", bind(&RequestHandler::whoami));
  router_.add("DELETE", "/v1/session", bind(&RequestHandler::logout));
  // Uploads stream (open_body_stream); this route serves a body already read whole
  // (respond_to_bytes, tests). The hashing and fsync may take long: off the I/O threads.
  router_.add("PUT", "/v1/assets/{name}", bind(&RequestHandler::put_asset), Lane::blocking);
  router_.add("HEAD", "/v1/assets/{name}", bind(&RequestHandler::head_asset));
}

Lane RequestHandler::lane(const HttpRequest& request) const {
  const RouteMatch m = router_.match(request.method, request.path());
  return m.route ? m.route->lane : Lane::io;
}

HttpResponse RequestHandler::handle(HttpRequest http) {
  ApiRequest request(std::move(http));
  HttpResponse res = guarded(request, [&request](const RouteMatch& m) { return m.route->handler(request, m.params); });
  if (request.method == "HEAD") res.body.clear();  // a HEAD answer has no body, whatever went wrong
  return res;
}

HttpResponse RequestHandler::guarded(ApiRequest& request, const std::function<HttpResponse(const RouteMatch&)>& run) {
  const auto t0 = std::chrono::steady_clock::now();
  const RouteMatch m = router_.match(request.method, request.path());
  HttpResponse res;
  try {
    // The one authorize step: the caller, or 400/401/403/429 before any route runs.
    request.principal =
        std::make_shared<const Principal>(authorize(request, m.route ? m.route->pattern : "", config_.access));
    if (!m.route) {
      if (auto file = serve_static_file(request)) return *file;  // the preview page, examples
      if (!m.allow.empty()) {
        std::string allow;
        for (const auto& a : m.allow) allow += (allow.empty() ? "" : ", ") + a;
        HttpError e(405, fmt::format("{} is not allowed on {}; allowed: {}", request.method, request.path(), allow));
        e.headers.emplace_back("Allow", allow);
        throw e;
      }
      throw HttpError(404, fmt::format("no route for {}", request.path()));
    }
    // Until recovery is done the job routes would show a partial list: refuse them.
    if (!ready_ && !manager_.shutting_down() && request.path().substr(0, 4) == "/v1/" &&
        m.route->pattern != "/v1/openapi.json") {
      HttpError e(503, "the server is starting: jobs are being recovered; retry shortly");
      e.headers.emplace_back("Retry-After", "1");
      throw e;
    }
    res = run(m);
  } catch (const HttpError& e) {
    res = problem_response(e.status(), e.detail(), e.pointer());
    for (const auto& [k, v] : e.headers) res.set_header(k, v);
  } catch (const SpecError& e) {
    res = problem_response(422, e.detail(), e.pointer(), true);
  } catch (const JobError& e) {
    switch (e.kind()) {
      case JobError::Kind::not_found: res = problem_response(404, e.what()); break;
      case JobError::Kind::conflict: res = problem_response(409, e.what()); break;
      case JobError::Kind::queue_full:
        res = problem_response(503, e.what());
        res.set_header("Retry-After", "5");
        break;
      case JobError::Kind::unavailable:
        res = problem_response(503, e.what());
        res.set_header("Retry-After", "5");
        break;
      case JobError::Kind::quota: res = problem_response(403, e.what()); break;
    }
  } catch (const std::exception& e) {
    res = problem_response(500, fmt::format("internal error: {}", e.what()));
  }
  if (res.status == 0) return res;  // a streamed body continues (open_body_stream): observed when it ends
  if (res.header("X-Content-Type-Options").empty()) res.set_header("X-Content-Type-Options", "nosniff");
  const double dt = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  metrics_.observe(m.route ? m.route->pattern : std::string("unmatched"), request.method, res.status, dt);
  return res;
}

json RequestHandler::parse_json_body(const ApiRequest& request) const {
  const std::string_view ct = request.header("content-type");
  if (ct.empty() || !is_json_media_type(ct)) {
    throw HttpError(415, fmt::format("the request body must be application/json, got \"{}\"", ct));
  }
  if (request.body.empty()) throw HttpError(400, "the request body is empty; a JSON object is required");
  if (json_nesting_depth(request.body, config_.max_json_depth) > config_.max_json_depth) {
    throw HttpError(400, fmt::format("JSON nesting deeper than {} levels", config_.max_json_depth));
  }
  try {
    return json::parse(request.body);
  } catch (const json::parse_error& e) {
    throw HttpError(400, fmt::format("malformed JSON: {}", e.what()));
  } catch (const json::out_of_range& e) {  // a number beyond double range, e.g. 1e400
    const std::string at = json_pointer_at_error(request.body);
    throw HttpError(400, fmt::format("number out of range at \"{}\": {}", at, e.what()), at);
  }
}

// ---- browser sessions: EventSource cannot send an Authorization header, so the
// page trades a token for an HttpOnly, SameSite=Strict cookie once.

namespace {

// 429 with Retry-After (whole seconds, at least 1) when a login rate limit says wait.
void refuse_login_if(double wait, const std::string& whose) {
  if (wait <= 0) return;
  HttpError e(429, fmt::format("too many logins {}; retry in {:.0f} s", whose, std::ceil(wait)));
  e.headers.emplace_back("Retry-After", std::to_string(std::max(1L, static_cast<long>(std::ceil(wait)))));
  throw e;
}

}  // namespace

HttpResponse RequestHandler::login(const ApiRequest& req, const PathParams&) {
  const json body = parse_json_body(req);
  SpecReader rd(body, "");
  const std::string token = rd.string("token", 512);
  rd.finish();
  AccessControl* access = config_.access.access;
  if (!access) throw HttpError(404, "access control is off: no login is needed");
  // Every attempt counts against its address, before the token is looked at.
  refuse_login_if(access->take_login_attempt(req.peer_address), "from this address");
  const auto who = is_b64token(token) ? access->authenticate_token(token) : std::nullopt;
  if (!who) {
    HttpError e(401, "unknown or revoked token");
    e.headers.emplace_back("WWW-Authenticate", "Bearer realm=\"tally\", error=\"invalid_token\"");
    throw e;
  }
  if (who->role == Role::metrics) throw HttpError(403, "role metrics may not open a browser session");
  refuse_login_if(access->take_login(*who), fmt::format("for \"{}\"", who->name));
  const std::string sid = access->open_session(*who);
  HttpResponse r = json_response(200, {{"name", who->name}, {"role", std::string(role_name(who->role))},
                                       {"access_control", true}});
  r.set_header("Set-Cookie", fmt::format("{}={}; Path=/; HttpOnly; SameSite=Strict; Max-Age=43200{}", kSessionCookie,
                                         sid, config_.access.tls ? "; Secure" : ""));
  r.set_header("Cache-Control", "no-store");
  return r;
}

HttpResponse RequestHandler::whoami(const ApiRequest& req, const PathParams&) {
  const Principal& p = *req.principal;
  return json_response(200, {{"name", p.name},
                             {"role", std::string(role_name(p.role))},
                             {"access_control", config_.access.access != nullptr},
                             {"via_cookie", p.via_cookie}});
}

HttpResponse RequestHandler::logout(const ApiRequest& req, const PathParams&) {
  if (config_.access.access) {
    const std::string sid = cookie_value(req, kSessionCookie);
    if (!sid.empty()) config_.access.access->close_session(sid);  // its event streams end
  }
  HttpResponse r;
  r.status = 204;
  r.set_header("Set-Cookie", fmt::format("{}=; Path=/; HttpOnly; SameSite=Strict; Max-Age=0{}", kSessionCookie,
                                         config_.access.tls ? "; Secure" : ""));
  return r;
}

}  // namespace tally
