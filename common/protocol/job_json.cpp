#include "common/protocol/job_json.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <ctime>
#include <limits>

#include "common/hash/fnv1a.hpp"
#include "common/protocol/job_kinds.hpp"
#include "common/protocol/status_json.hpp"
#include "common/spec/stop_rule_json.hpp"

namespace tally {

using nlohmann::json;

std::string_view job_status_name(JobStatus s) {
  switch (s) {
    case JobStatus::queued: return "queued";
    case JobStatus::running: return "running";
    case JobStatus::succeeded: return "succeeded";
    case JobStatus::failed: return "failed";
    case JobStatus::cancelled: return "cancelled";
  }
  return "unknown";
}

std::optional<JobStatus> parse_job_status(std::string_view s) {
  for (JobStatus x : {JobStatus::queued, JobStatus::running, JobStatus::succeeded, JobStatus::failed,
                      JobStatus::cancelled}) {
    if (job_status_name(x) == s) return x;
  }
  return std::nullopt;
}

json time_json(double t) {
  if (t <= 0) return nullptr;
  const auto secs = static_cast<std::time_t>(std::floor(t));
  const int ms = std::min(999, static_cast<int>((t - std::floor(t)) * 1000.0));
  std::tm tm{};
  gmtime_r(&secs, &tm);
  return fmt::format("{:04}-{:02}-{:02}T{:02}:{:02}:{:02}.{:03}Z", tm.tm_year + 1900, tm.tm_mon + 1, tm.tm_mday,
                     tm.tm_hour, tm.tm_min, tm.tm_sec, ms);
}

json tally_bits_json(const JobState& state) {
  if (state.channels.empty()) {
    // Sum channels (an image with replicates): the first one's bits, its tile's samples,
    // and the FNV-1a of the first 65,536 sums' bits (4 bytes each, little-endian): a whole
    // first tile, which the first sum alone (often a black pixel's 0) would not tell apart.
    if (state.sums.empty() || state.partition_samples.empty()) return nullptr;
    uint64_t h = kFnv1a64Basis;
    for (size_t i = 0; i < std::min<size_t>(state.sums.size(), 65536); ++i) {
      const uint32_t v = std::bit_cast<uint32_t>(state.sums[i]);
      char le[4];
      for (int b = 0; b < 4; ++b) le[b] = static_cast<char>((v >> (8 * b)) & 0xff);
      h = fnv1a64_update(h, std::string_view(le, 4));
    }
    return {{"n", state.partition_samples[0]},
            {"sum", fmt::format("{:08x}", std::bit_cast<uint32_t>(state.sums[0]))},
            {"sums_fnv1a", fmt::format("{:016x}", h)}};
  }
  const Tally& t = state.channels[0];
  return {{"n", t.n},
          {"mean", fmt::format("{:016x}", std::bit_cast<uint64_t>(t.mean))},
          {"m2", fmt::format("{:016x}", std::bit_cast<uint64_t>(t.m2))}};
}

json eta_json(const JobRunner& r) {
  if (r.finished()) return 0.0;
  const double eta = r.eta_seconds();
  return std::isfinite(eta) ? json(eta) : json(nullptr);
}

json progress_event_json(const JobRunner& r) {
  json j = progress_json(r);
  j["pass"] = r.state().passes;
  j["eta_seconds"] = eta_json(r);
  return j;
}

json state_event_json(JobStatus status, const JobRunner* runner, const std::string& error, bool end) {
  if (!runner) return state_event_json(status, static_cast<const RunFacts*>(nullptr), error, end);
  RunFacts facts;  // the two facts the event shows, read from the runner
  facts.stop_reason = runner->stop_reason();
  facts.target_met = end && runner->target_met();
  return state_event_json(status, &facts, error, end);
}

json state_event_json(JobStatus status, const RunFacts* facts, const std::string& error, bool end) {
  json st = {{"state", std::string(job_status_name(status))}};
  if (facts) {
    st["stop_reason"] = std::string(stop_reason_name(facts->stop_reason));
    if (end) st["target_met"] = facts->target_met;
  }
  if (!error.empty()) st["error_message"] = error;
  return st;
}

namespace {
// run_facts without the progress event (the list does not show it).
RunFacts run_facts_light(const JobRunner& r) {
  RunFacts f;
  const JobState& s = r.state();
  f.samples = s.samples;
  f.passes = s.passes;
  if ((s.channels.empty() ? s.samples : s.channels[0].n) > 0) f.headline = r.headline();
  f.stop_reason = r.stop_reason();
  f.results_version = s.results_version;
  return f;
}
}  // namespace

RunFacts live_run_facts(const JobRunner& r) {
  RunFacts f = run_facts_light(r);
  f.rule = r.rule();
  f.compute_seconds = r.state().compute_seconds;
  return f;
}

RunFacts run_facts(const JobRunner& r, const std::string* progress_event) {
  RunFacts f = live_run_facts(r);
  f.target_met = r.target_met();
  if (r.state().passes > 0) {
    f.progress_event = progress_event ? *progress_event
                                      : progress_event_json(r).dump(-1, ' ', false, json::error_handler_t::replace);
  }
  return f;
}

RunFacts fresh_run_facts(const StopRule& rule) {
  RunFacts f;
  f.rule = rule;
  return f;
}

json run_facts_json(const RunFacts& f) {
  json j = {{"samples", f.samples},
            {"passes", f.passes},
            {"stop_reason", std::string(stop_reason_name(f.stop_reason))},
            {"target_met", f.target_met},
            {"compute_seconds", f.compute_seconds},
            {"progress_event", f.progress_event},
            {"results_version", f.results_version}};
  if (f.headline) {
    // Non-finite values are stored as null and read back as NaN (the views print null).
    const auto num = [](double x) { return std::isfinite(x) ? json(x) : json(nullptr); };
    j["headline"] = {{"mean", num(f.headline->mean)}, {"std_error", num(f.headline->std_error)}};
  }
  return j;
}

RunFacts parse_run_facts(const json& j, const StopRule& rule) {
  RunFacts f;
  f.rule = rule;
  f.samples = j.at("samples").get<uint64_t>();
  f.passes = j.at("passes").get<uint64_t>();
  const std::string reason = j.at("stop_reason").get<std::string>();
  bool known = false;
  for (StopReason r : {StopReason::none, StopReason::max_samples, StopReason::time_budget, StopReason::error_target,
                       StopReason::cancelled, StopReason::failed, StopReason::sample_cap}) {
    if (stop_reason_name(r) == reason) {
      f.stop_reason = r;
      known = true;
    }
  }
  if (!known) throw std::invalid_argument("unknown stop_reason \"" + reason + "\"");
  f.target_met = j.at("target_met").get<bool>();
  f.compute_seconds = j.at("compute_seconds").get<double>();
  f.progress_event = j.at("progress_event").get<std::string>();
  // Facts stored before the results version was recorded read as 0 (unknown).
  f.results_version = j.value("results_version", uint32_t{0});
  if (j.contains("headline")) {
    const auto num = [](const json& x) {
      return x.is_null() ? std::numeric_limits<double>::quiet_NaN() : x.get<double>();
    };
    Estimate e;
    e.mean = num(j.at("headline").at("mean"));
    e.std_error = num(j.at("headline").at("std_error"));
    f.headline = e;
  }
  return f;
}

json engine_json(const JobDefinition& def, const JobRunner& runner) {
  json j = result_json(runner, def);
  j["summary"] = def.summary_line(runner);
  j["eta_seconds"] = eta_json(runner);
  j["bits"] = tally_bits_json(runner.state());
  return j;
}

json status_json(const JobSnapshot& job, double now, json links) {
  json j;
  if (is_terminal(job.status) && job.final_result && !job.final_result->is_null()) {
    j = *job.final_result;
  } else if (job.engine) {
    j = *job.engine;
  } else if (job.runner && job.def) {
    j = engine_json(*job.def, *job.runner);
  } else {
    j = json::object();
  }
  j["id"] = job.id;
  j["state"] = std::string(job_status_name(job.status));
  j["priority"] = job.priority;
  if (!job.owner.empty()) j["owner"] = job.owner;
  if (!job.cached_from.empty()) j["cached_from"] = job.cached_from;
  j["spec"] = job.spec ? *job.spec : json(nullptr);
  j["plan"] = job.def ? plan_json(*job.def) : json(nullptr);
  if (job.runner) {
    j["stop_rule"] = stop_rule_to_json(job.runner->rule());
  } else if (job.facts) {
    j["stop_rule"] = stop_rule_to_json(job.facts->rule);
  }
  if (!job.error.empty()) j["error_message"] = job.error;
  if (job.status == JobStatus::queued && !job.executor.waiting_reason.empty()) {
    j["waiting_reason"] = job.executor.waiting_reason;  // "preempted": paused for a job that went first
  }
  if (job.status == JobStatus::running || job.executor.held_queued) {
    if (!job.executor.waiting_reason.empty()) j["waiting_reason"] = job.executor.waiting_reason;
    if (job.executor.has_blocks) {
      j["blocks"] = {{"pending", job.executor.pending},
                     {"in_flight", job.executor.in_flight},
                     {"redelivered", job.executor.redelivered}};
    }
  }
  const double end = job.finished_at > 0 ? job.finished_at : now;
  j["timing"] = {{"created_at", time_json(job.created_at)},
                 {"started_at", time_json(job.started_at)},
                 {"finished_at", time_json(job.finished_at)},
                 {"queued_seconds", (job.started_at > 0 ? job.started_at : now) - job.created_at},
                 {"wall_seconds", job.started_at > 0 ? end - job.started_at : 0.0},
                 {"compute_seconds", job.runner  ? job.runner->state().compute_seconds
                                     : job.facts ? job.facts->compute_seconds
                                                 : 0.0}};
  j["links"] = std::move(links);
  return j;
}

json summary_json(const JobSnapshot& job) {
  json j;
  j["id"] = job.id;
  j["state"] = std::string(job_status_name(job.status));
  j["kind"] = job.spec && job.spec->is_object() ? job.spec->value("kind", "") : std::string();
  if (job.spec && job.spec->is_object() && job.spec->contains("name") && (*job.spec)["name"].is_string()) {
    j["name"] = (*job.spec)["name"];  // what the user called it (the list, the page)
  }
  j["priority"] = job.priority;
  if (!job.owner.empty()) j["owner"] = job.owner;
  j["created_at"] = time_json(job.created_at);
  // The runner's figures, or the same figures kept when its state left memory.
  const std::optional<RunFacts> f = job.runner ? std::optional<RunFacts>(run_facts_light(*job.runner))
                                    : job.facts ? std::optional<RunFacts>(*job.facts)
                                                : std::nullopt;
  if (f) {
    j["samples"] = f->samples;
    j["passes"] = f->passes;
    if (f->headline) {  // an image job's mean radiance, else channel 0
      j["mean"] = std::isfinite(f->headline->mean) ? json(f->headline->mean) : json(nullptr);
      j["std_error"] = std::isfinite(f->headline->std_error) ? json(f->headline->std_error) : json(nullptr);
    }
    j["stop_reason"] = std::string(stop_reason_name(f->stop_reason));
  }
  if (!job.error.empty()) j["error_message"] = job.error;
  if (job.status == JobStatus::queued && !job.executor.waiting_reason.empty()) {
    j["waiting_reason"] = job.executor.waiting_reason;
  }
  if (!job.cached_from.empty()) j["cached_from"] = job.cached_from;
  return j;
}

}  // namespace tally
