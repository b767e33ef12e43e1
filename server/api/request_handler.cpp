#include "server/api/request_handler.hpp"

#include <fmt/format.h>

#include <charconv>
#include <chrono>
#include <cmath>

#include "common/json/spec_reader.hpp"
#include "common/protocol/stop_rule_json.hpp"
#include "server/api/job_event_stream.hpp"
#include "server/api/json_depth.hpp"
#include "server/api/pilot.hpp"
#include "server/api/problem.hpp"
#include "server/api/static_files.hpp"

namespace tally {

using nlohmann::json;

namespace {

HttpResponse json_response(int status, const json& j) {
  HttpResponse r;
  r.status = status;
  r.set_header("Content-Type", "application/json");
  r.body = j.dump(-1, ' ', false, json::error_handler_t::replace);
  r.body.push_back('\n');
  return r;
}

bool is_json_media_type(std::string_view ct) {
  const size_t semi = ct.find(';');
  std::string_view type = ct.substr(0, semi);
  while (!type.empty() && type.back() == ' ') type.remove_suffix(1);
  while (!type.empty() && type.front() == ' ') type.remove_prefix(1);
  if (iequals(type, "application/json")) return true;
  // application/*+json (e.g. a client sending problem+json back at us) is JSON too.
  return type.size() > 17 && iequals(type.substr(0, 12), "application/") && iequals(type.substr(type.size() - 5), "+json");
}

std::optional<uint64_t> parse_u64(std::string_view s) {
  while (!s.empty() && s.front() == ' ') s.remove_prefix(1);
  while (!s.empty() && s.back() == ' ') s.remove_suffix(1);
  uint64_t v = 0;
  auto [p, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
  if (ec != std::errc() || p != s.data() + s.size() || s.empty()) return std::nullopt;
  return v;
}

int parse_priority(const HttpRequest& req) {
  if (!req.has_query_param("priority")) return 0;
  const std::string p = req.query_param("priority");
  int v = 0;
  auto [ptr, ec] = std::from_chars(p.data(), p.data() + p.size(), v);
  if (ec != std::errc() || ptr != p.data() + p.size() || v < -5 || v > 5) {
    throw HttpError(400, fmt::format("query parameter priority must be an integer in [-5, 5], got \"{}\"", p));
  }
  return v;
}

}  // namespace

RequestHandler::RequestHandler(JobManager& manager, Metrics& metrics, HandlerConfig config)
    : manager_(manager), metrics_(metrics), config_(std::move(config)) {
  add_routes();
}

void RequestHandler::add_routes() {
  using namespace std::placeholders;
  auto bind = [this](HttpResponse (RequestHandler::*fn)(const HttpRequest&, const PathParams&)) {
    return [this, fn](const HttpRequest& r, const PathParams& p) { return (this->*fn)(r, p); };
  };
  router_.add("GET", "/livez", [](const HttpRequest&, const PathParams&) {
    HttpResponse r;
    r.set_header("Content-Type", "text/plain; charset=utf-8");
    r.body = "ok\n";
    return r;
  });
  router_.add("GET", "/readyz", [this](const HttpRequest&, const PathParams&) {
    if (!ready_ || manager_.shutting_down()) throw HttpError(503, "the server is not ready (starting or shutting down)");
    if (auto why = manager_.executor_not_ready()) throw HttpError(503, "the server is not ready: " + *why);
    HttpResponse r;
    r.set_header("Content-Type", "text/plain; charset=utf-8");
    r.body = "ready\n";
    return r;
  });
  router_.add("GET", "/metrics", [this](const HttpRequest&, const PathParams&) {
    HttpResponse r;
    r.set_header("Content-Type", "text/plain; version=0.0.4; charset=utf-8");
    r.body = metrics_.render(manager_.stats());
    if (config_.extra_metrics) r.body += config_.extra_metrics();
    return r;
  });
  router_.add("GET", "/v1/workers", [this](const HttpRequest&, const PathParams&) {
    HttpResponse r;
    r.set_header("Content-Type", "application/json");
    const json j = config_.workers ? config_.workers() : json{{"executor", "in_process"}, {"workers", json::array()}};
    r.body = j.dump();
    r.body.push_back('\n');
    return r;
  });
  router_.add("GET", "/v1/openapi.json", [](const HttpRequest&, const PathParams&) {
    HttpResponse r;
    r.set_header("Content-Type", "application/json");
    r.body = openapi_document();
    return r;
  });
  router_.add("POST", "/v1/jobs", bind(&RequestHandler::post_job), true);
  router_.add("GET", "/v1/jobs", bind(&RequestHandler::list_jobs));
  router_.add("POST", "/v1/jobs/validate", bind(&RequestHandler::validate_job), true);
  router_.add("GET", "/v1/jobs/{id}", bind(&RequestHandler::get_job));
  router_.add("DELETE", "/v1/jobs/{id}", bind(&RequestHandler::delete_job));
  router_.add("POST", "/v1/jobs/{id}/extend", bind(&RequestHandler::extend_job));
  router_.add("GET", "/v1/jobs/{id}/events", bind(&RequestHandler::job_events));
  router_.add("GET", "/v1/jobs/{id}/tiles/{n}", bind(&RequestHandler::job_tile));
  router_.add("GET", "/v1/jobs/{id}/image.exr",
              [this](const HttpRequest& r, const PathParams& p) { return job_image(r, p, true); }, true);
  router_.add("GET", "/v1/jobs/{id}/image.png",
              [this](const HttpRequest& r, const PathParams& p) { return job_image(r, p, false); }, true);
}

bool RequestHandler::may_block(const HttpRequest& request) const {
  const RouteMatch m = router_.match(request.method, request.path());
  return m.route && m.route->may_block;
}

HttpResponse RequestHandler::handle(const HttpRequest& request) {
  const auto t0 = std::chrono::steady_clock::now();
  const RouteMatch m = router_.match(request.method, request.path());
  HttpResponse res;
  try {
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
    res = m.route->handler(request, m.params);
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
    }
  } catch (const std::exception& e) {
    res = problem_response(500, fmt::format("internal error: {}", e.what()));
  }
  const double dt = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  metrics_.observe(m.route ? m.route->pattern : std::string("unmatched"), request.method, res.status, dt);
  return res;
}

json RequestHandler::parse_json_body(const HttpRequest& request) const {
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
  }
}

std::shared_ptr<Job> RequestHandler::job_or_404(const std::string& id) const {
  auto job = manager_.find(id);
  if (!job) throw HttpError(404, fmt::format("no job with id \"{}\"", id));
  return job;
}

HttpResponse RequestHandler::post_job(const HttpRequest& req, const PathParams&) {
  const int priority = parse_priority(req);
  const json spec = parse_json_body(req);
  auto job = manager_.submit(spec, priority);
  const json summary = manager_.summary_json(*job);
  HttpResponse r = json_response(202, {{"id", job->id},
                                       {"state", summary["state"]},
                                       {"links", {{"self", "/v1/jobs/" + job->id}, {"events", "/v1/jobs/" + job->id + "/events"}}}});
  r.set_header("Location", "/v1/jobs/" + job->id);
  return r;
}

HttpResponse RequestHandler::list_jobs(const HttpRequest& req, const PathParams&) {
  std::optional<JobStatus> filter;
  if (req.has_query_param("state")) {
    filter = parse_job_status(req.query_param("state"));
    if (!filter) {
      throw HttpError(400, fmt::format("query parameter state must be one of queued, running, succeeded, failed, "
                                       "cancelled; got \"{}\"", req.query_param("state")));
    }
  }
  json jobs = json::array();
  for (const auto& job : manager_.list()) {
    json s = manager_.summary_json(*job);
    if (filter && s["state"] != job_status_name(*filter)) continue;
    jobs.push_back(std::move(s));
  }
  return json_response(200, {{"jobs", jobs}});
}

HttpResponse RequestHandler::get_job(const HttpRequest&, const PathParams& p) {
  auto job = job_or_404(p.at("id"));
  HttpResponse r;
  r.set_header("Content-Type", "application/json");
  r.body = manager_.status_body(*job);
  return r;
}

HttpResponse RequestHandler::delete_job(const HttpRequest&, const PathParams& p) {
  auto job = manager_.cancel(p.at("id"));
  json s = manager_.summary_json(*job);
  // 200 when the job is already cancelled, 202 when it stops at the next chunk boundary.
  return json_response(s["state"] == "cancelled" ? 200 : 202, s);
}

HttpResponse RequestHandler::extend_job(const HttpRequest& req, const PathParams& p) {
  const json body = parse_json_body(req);
  auto job = job_or_404(p.at("id"));
  StopRule rule;
  {
    std::lock_guard lock(job->mu);
    if (job->runner) {
      rule.confidence = job->runner->rule().confidence;
      rule.min_samples = job->runner->rule().min_samples;
    }
  }
  const JobLimits& lim = manager_.config().limits;
  SpecReader rd(body, "");
  rule.max_samples = rd.integer_or("max_samples", 0, 1, lim.max_samples);
  rule.abs_error = rd.number_or("abs_error", 0.0, 1e-300, 1e300);
  rule.rel_error = rd.number_or("rel_error", 0.0, 1e-12, 1e3);
  rule.time_budget_s = rd.number_or("time_budget_s", 0.0, 1e-3, lim.max_seconds);
  rd.finish();
  if (rule.max_samples == 0 && rule.time_budget_s == 0.0 && !rule.has_error_target()) {
    throw SpecError("", "needs at least one of max_samples, abs_error, rel_error, time_budget_s");
  }
  manager_.extend(job->id, rule);
  return json_response(202, manager_.summary_json(*job));
}

HttpResponse RequestHandler::validate_job(const HttpRequest& req, const PathParams&) {
  const json spec = parse_json_body(req);
  std::unique_ptr<JobDefinition> def = manager_.compiler()(spec, manager_.config().limits);
  json out = {{"valid", true},
              {"kind", std::string(def->kind())},
              {"plan", def->plan()},
              {"stop_rule", stop_rule_to_json(def->stop_rule())}};
  if (pilots_.fetch_add(1) >= config_.max_concurrent_pilots) {
    pilots_.fetch_sub(1);
    out["pilot"] = nullptr;
    out["prediction"] = nullptr;
    out["note"] = "too many pilots running; the spec is valid but no prediction was made";
    return json_response(200, out);
  }
  PilotOptions po;
  po.seconds = config_.pilot_seconds;
  po.caps = manager_.config().caps;
  po.parallelism = manager_.config().workers;
  json pilot;
  try {
    pilot = run_pilot(*def, po);
  } catch (...) {
    pilots_.fetch_sub(1);
    throw;
  }
  pilots_.fetch_sub(1);
  out["pilot"] = pilot["pilot"];
  out["prediction"] = pilot["prediction"];
  return json_response(200, out);
}

HttpResponse RequestHandler::job_events(const HttpRequest& req, const PathParams& p) {
  auto job = job_or_404(p.at("id"));
  const std::string_view accept = req.header("accept");
  const StreamFormat fmt = accept.find("application/x-ndjson") != std::string_view::npos ? StreamFormat::ndjson
                                                                                          : StreamFormat::sse;
  std::optional<uint64_t> last = parse_u64(req.header("last-event-id"));
  if (!last && req.has_query_param("last_event_id")) last = parse_u64(req.query_param("last_event_id"));
  HttpResponse r;
  r.set_header("Content-Type", fmt == StreamFormat::ndjson ? "application/x-ndjson" : "text/event-stream");
  r.set_header("Cache-Control", "no-cache");
  r.set_header("X-Accel-Buffering", "no");
  r.stream = std::make_shared<JobEventStream>(job, manager_, fmt, last);
  return r;
}

HttpResponse RequestHandler::job_tile(const HttpRequest&, const PathParams& p) {
  auto job = job_or_404(p.at("id"));
  const auto n = parse_u64(p.at("n"));
  std::lock_guard lock(job->mu);
  const ImageSource* img = job->def ? job->def->image() : nullptr;
  if (!img) throw HttpError(404, fmt::format("job {} has no image", job->id));
  if (!n || *n >= img->tile_count()) {
    throw HttpError(404, fmt::format("tile \"{}\" does not exist; the image has {} tiles", p.at("n"), img->tile_count()));
  }
  if (!job->runner) throw HttpError(409, "the job's state is not available");
  const TileRect rc = img->tile_rect(static_cast<uint32_t>(*n));
  const ImageSnapshot s = img->snapshot(job->runner->state(), rc);
  return json_response(200, {{"tile", *n},
                             {"x", rc.x}, {"y", rc.y}, {"w", rc.w}, {"h", rc.h},
                             {"pass", job->runner->state().passes},
                             {"mean", s.rgb},
                             {"std_error", s.stderr_rgb},
                             {"samples", s.samples}});
}

HttpResponse RequestHandler::job_image(const HttpRequest&, const PathParams& p, bool exr) {
  auto job = job_or_404(p.at("id"));
  ImageSnapshot snap;
  json meta;
  {
    std::lock_guard lock(job->mu);
    const ImageSource* img = job->def ? job->def->image() : nullptr;
    if (!img) throw HttpError(404, fmt::format("job {} has no image", job->id));
    if (!job->runner) throw HttpError(409, "the job's state is not available");
    if ((exr && !config_.images.exr) || (!exr && !config_.images.png)) {
      throw HttpError(501, "image encoding is not available in this build");
    }
    snap = img->snapshot(job->runner->state());
    meta = {{"job_id", job->id},
            {"state", std::string(job_status_name(job->status))},
            {"samples", job->runner->state().samples},
            {"passes", job->runner->state().passes},
            {"spec", job->spec}};
  }
  HttpResponse r;
  r.set_header("Content-Type", exr ? "image/x-exr" : "image/png");
  r.set_header("Content-Disposition", fmt::format("inline; filename=\"{}.{}\"", job->id, exr ? "exr" : "png"));
  r.body = exr ? config_.images.exr(snap, meta) : config_.images.png(snap);
  return r;
}

}  // namespace tally
