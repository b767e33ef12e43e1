// The job routes: POST/GET /v1/jobs, GET/PATCH/DELETE /v1/jobs/{id}, extend, validate,
// events. Each reads a JobSnapshot from the manager (never a job's lock) and
// renders it with the protocol layer's views (common/protocol/job_json.hpp).
#include <fmt/format.h>

#include <algorithm>

#include "common/protocol/job_json.hpp"
#include "common/protocol/job_kinds.hpp"
#include "common/spec/pool_field.hpp"
#include "common/spec/priority_field.hpp"
#include "common/spec/spec_reader.hpp"
#include "common/spec/stop_rule_json.hpp"
#include "server/api/estimator_suggestion.hpp"
#include "server/api/job_event_stream.hpp"
#include "server/api/pilot.hpp"
#include "server/api/request_handler.hpp"
#include "server/api/route_support.hpp"
#include "server/auth/revocation.hpp"

namespace tally {

using nlohmann::json;

std::string StatusCache::body(const JobSnapshot& job, const std::function<std::string()>& build) {
  const auto now = std::chrono::steady_clock::now();
  {
    std::lock_guard lock(mu_);
    auto it = entries_.find(job.id);
    // The statistics change only at pass boundaries (version); the timing fields
    // of a running job also change with the clock, so its copy lives at most 1 s.
    if (it != entries_.end() && it->second.version == job.version &&
        (is_terminal(job.status) || now - it->second.at < std::chrono::seconds(1))) {
      return it->second.body;
    }
  }
  std::string body = build();
  std::lock_guard lock(mu_);
  if (entries_.size() >= kMaxEntries) entries_.clear();  // bounded: deleted jobs leave no entry behind for long
  Entry& e = entries_[job.id];
  if (e.version <= job.version) e = Entry{job.version, body, now};
  return body;
}

std::shared_ptr<Job> RequestHandler::visible_job(const ApiRequest& req, const std::string& id) const {
  auto job = manager_.find(id);
  if (!job || !req.principal || !req.principal->may_see(job->owner())) {
    throw HttpError(404, fmt::format("no job with id \"{}\"", id));
  }
  return job;
}

JobSnapshot RequestHandler::visible_snapshot(const ApiRequest& req, const std::string& id,
                                             JobManager::SnapshotOf of) const {
  return manager_.snapshot(*visible_job(req, id), of);
}

Submitter RequestHandler::submitter(const ApiRequest& req) const {
  Submitter s;
  const Principal& p = *req.principal;
  s.owner = p.name;
  const Quotas& q = p.quotas;
  s.max_running = q.max_running_jobs;
  s.max_queued = q.max_queued_jobs;
  s.reads_all = p.is_admin();
  JobLimits limits = manager_.config().limits;
  limits.max_samples = std::min<uint64_t>(limits.max_samples, q.max_samples);
  limits.max_seconds = std::min(limits.max_seconds, q.max_seconds);
  limits.max_pixels = std::min<uint64_t>(limits.max_pixels, q.max_pixels);
  limits.may_read_asset = asset_reader_of(p);
  s.limits = limits;
  return s;
}

void RequestHandler::check_pool(const ApiRequest& req, const json& spec) const {
  const Principal& p = *req.principal;
  if (p.pools.empty()) return;
  const std::string pool = spec_pool(spec);
  const std::string allowed = fmt::format("\"{}\"", fmt::join(p.pools, "\", \""));
  if (pool.empty()) {
    throw HttpError(403, fmt::format("principal \"{}\" may only run jobs in the worker pools {}: the spec must name one",
                                     p.name, allowed),
                    "/pool");
  }
  if (std::find(p.pools.begin(), p.pools.end(), pool) == p.pools.end()) {
    throw HttpError(403, fmt::format("principal \"{}\" may not use worker pool \"{}\"; its pools are {}", p.name, pool,
                                     allowed),
                    "/pool");
  }
}

HttpResponse RequestHandler::post_job(const ApiRequest& req, const PathParams&) {
  const int priority = parse_priority(req);
  const json spec = parse_json_body(req);
  check_assets(req, spec);
  // ?cache=false: compute even if a finished job with the same spec and seed is readable.
  bool use_cache = true;
  if (req.has_query_param("cache")) {
    const std::string c = req.query_param("cache");
    if (c != "true" && c != "false") {
      throw HttpError(400, fmt::format("query parameter cache must be true or false; got \"{}\"", c));
    }
    use_cache = c == "true";
  }
  check_pool(req, spec);
  auto job = manager_.submit(spec, priority, submitter(req), use_cache);
  const JobSnapshot s = manager_.snapshot(*job);
  HttpResponse r = json_response(202, {{"id", s.id},
                                       {"state", std::string(job_status_name(s.status))},
                                       {"links", job_links(s.id, false)}});
  r.set_header("Location", job_links(s.id, false).at("self").get<std::string>());
  return r;
}

HttpResponse RequestHandler::list_jobs(const ApiRequest& req, const PathParams&) {
  std::optional<JobStatus> filter;
  if (req.has_query_param("state")) {
    filter = parse_job_status(req.query_param("state"));
    if (!filter) {
      throw HttpError(400, fmt::format("query parameter state must be one of queued, running, succeeded, failed, "
                                       "cancelled; got \"{}\"", req.query_param("state")));
    }
  }
  // Pages in submission order; the cursor is the last listed job's sequence number,
  // so jobs submitted or deleted meanwhile neither repeat nor shift the pages.
  uint64_t limit = kListDefaultLimit;
  if (req.has_query_param("limit")) {
    const auto l = parse_u64(req.query_param("limit"));
    if (!l || *l < 1 || *l > kListMaxLimit) {
      throw HttpError(400, fmt::format("query parameter limit must be an integer from 1 to {}; got \"{}\"",
                                       kListMaxLimit, req.query_param("limit")));
    }
    limit = *l;
  }
  int64_t after = 0;
  if (req.has_query_param("cursor")) {
    const auto c = parse_u64(req.query_param("cursor"));
    if (!c || *c > static_cast<uint64_t>(INT64_MAX)) {
      throw HttpError(400, fmt::format("query parameter cursor is not a cursor this server gave: \"{}\"",
                                       req.query_param("cursor")));
    }
    after = static_cast<int64_t>(*c);
  }
  json jobs = json::array();
  int64_t last = 0;
  bool more = false;
  for (const auto& job : manager_.list()) {
    if (job->seq() <= after || !req.principal->may_see(job->owner())) continue;
    const JobSnapshot s = manager_.snapshot(*job);
    if (filter && s.status != *filter) continue;
    if (jobs.size() == limit) {
      more = true;
      break;
    }
    jobs.push_back(summary_json(s));
    last = s.seq;
  }
  json body = {{"jobs", std::move(jobs)}};
  if (!more) return json_response(200, body);  // the last page reads as before pagination
  std::string next = fmt::format("/v1/jobs?limit={}&cursor={}", limit, last);
  if (filter) next += fmt::format("&state={}", job_status_name(*filter));
  body["next"] = next;
  HttpResponse r = json_response(200, body);
  r.set_header("Link", fmt::format("<{}>; rel=\"next\"", next));
  return r;
}

HttpResponse RequestHandler::get_job(const ApiRequest& req, const PathParams& p) {
  const JobSnapshot s = visible_snapshot(req, p.at("id"));
  HttpResponse r;
  r.set_header("Content-Type", "application/json");
  r.body = status_cache_.body(s, [&] {
    const bool image = s.def && s.def->image();
    std::string body = status_json(s, unix_now(), job_links(s.id, image))
                           .dump(-1, ' ', false, json::error_handler_t::replace);
    body.push_back('\n');
    return body;
  });
  return r;
}

HttpResponse RequestHandler::delete_job(const ApiRequest& req, const PathParams& p) {
  const std::string id = visible_job(req, p.at("id"))->id();
  if (is_terminal(manager_.snapshot(id).status)) {
    // A finished job is deleted with its stored state: 204, then 404.
    manager_.remove(id);
    HttpResponse r;
    r.status = 204;
    return r;
  }
  auto job = manager_.cancel(id);
  const JobSnapshot s = manager_.snapshot(*job);
  // 200 when the job is already cancelled, 202 when it stops at the next chunk boundary.
  return json_response(s.status == JobStatus::cancelled ? 200 : 202, summary_json(s));
}

HttpResponse RequestHandler::patch_job(const ApiRequest& req, const PathParams& p) {
  const std::string id = visible_job(req, p.at("id"))->id();
  manager_.set_priority(id, read_priority_change(parse_json_body(req)));
  return json_response(200, summary_json(manager_.snapshot(id)));
}

HttpResponse RequestHandler::extend_job(const ApiRequest& req, const PathParams& p) {
  const JobSnapshot before = visible_snapshot(req, p.at("id"));
  const json body = parse_json_body(req);
  // The job keeps its confidence and min_samples; the body sets the new targets.
  const StopRule keep = before.runner ? before.runner->rule() : before.facts ? before.facts->rule : StopRule{};
  SpecReader rd(body, "");
  const StopRule rule = parse_stop_rule(rd, *submitter(req).limits, &keep);
  manager_.extend(before.id, rule, submitter(req));
  return json_response(202, summary_json(manager_.snapshot(before.id)));
}

HttpResponse RequestHandler::validate_job(const ApiRequest& req, const PathParams&) {
  const json spec = parse_json_body(req);
  check_assets(req, spec);
  check_pool(req, spec);
  const Submitter who = submitter(req);
  const JobLimits limits = *who.limits;
  // Within the memory budget: the pilot would allocate the state too.
  std::unique_ptr<JobDefinition> def = manager_.compile(spec, limits);
  manager_.check_room(who);  // the pilot computes as a job would: the same room
  json out = {{"valid", true},
              {"kind", std::string(def->kind())},
              {"plan", plan_json(*def)},
              {"stop_rule", stop_rule_to_json(def->stop_rule())}};
  if (pilots_.fetch_add(1) >= config_.max_concurrent_pilots) {
    pilots_.fetch_sub(1);
    out["pilot"] = nullptr;
    out["prediction"] = nullptr;
    out["note"] = "too many pilots running; the spec is valid but no prediction was made";
    return json_response(200, out);
  }
  // The pilot's state is charged against the memory budget like a job's.
  const uint64_t pilot_bytes = JobManager::state_bytes(*def);
  if (!manager_.reserve_memory(pilot_bytes)) {
    pilots_.fetch_sub(1);
    out["pilot"] = nullptr;
    out["prediction"] = nullptr;
    out["note"] = "the memory budget is in use by running jobs; the spec is valid but no prediction was made";
    return json_response(200, out);
  }
  PilotOptions po;
  po.seconds = config_.pilot_seconds;
  po.caps = limits.caps();
  po.parallelism = manager_.config().workers;
  json pilot;
  try {
    pilot = run_pilot(*def, po);
  } catch (...) {
    manager_.release_memory(pilot_bytes);
    pilots_.fetch_sub(1);
    throw;  // handle() maps it to a problem response
  }
  manager_.release_memory(pilot_bytes);
  pilots_.fetch_sub(1);
  if (pilot["pilot"].contains("error")) {
    throw SpecError("", fmt::format("the pilot run failed, as the job would: {}",
                                    pilot["pilot"]["error"].get<std::string>()));
  }
  out["pilot"] = pilot["pilot"];
  out["prediction"] = pilot["prediction"];
  const auto compile = [&](const json& s) { return manager_.compile(s, limits); };
  if (auto s = estimator_suggestion(spec, *def, out["prediction"], compile)) out["suggestion"] = std::move(*s);
  return json_response(200, out);
}

HttpResponse RequestHandler::job_events(const ApiRequest& req, const PathParams& p) {
  auto job = visible_job(req, p.at("id"));
  const std::string_view accept = req.header("accept");
  const StreamFormat fmt = accept.find("application/x-ndjson") != std::string_view::npos ? StreamFormat::ndjson
                                                                                          : StreamFormat::sse;
  std::optional<uint64_t> last = parse_last_event_id(req.header("last-event-id"));
  if (!last && req.has_query_param("last_event_id")) last = parse_last_event_id(req.query_param("last_event_id"));
  HttpResponse r;
  r.set_header("Content-Type", fmt == StreamFormat::ndjson ? "application/x-ndjson" : "text/event-stream");
  r.set_header("Cache-Control", "no-cache");
  r.set_header("X-Accel-Buffering", "no");
  // Ends when the caller's token is revoked or its browser session logs out.
  r.stream = revocable(std::make_shared<JobEventStream>(job, manager_, fmt, last), req.principal->principal_revocation,
                       req.principal->session_revocation);
  return r;
}

}  // namespace tally
