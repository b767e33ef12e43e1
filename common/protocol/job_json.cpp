#include "common/protocol/job_json.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <ctime>
#include <limits>

#include "common/protocol/kind_json.hpp"
#include "common/protocol/status_json.hpp"
#include "common/protocol/stop_rule_json.hpp"

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
  if (state.channels.empty()) return nullptr;
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
  json st = {{"state", std::string(job_status_name(status))}};
  if (runner) {
    st["stop_reason"] = std::string(stop_reason_name(runner->stop_reason()));
    if (end) st["target_met"] = runner->target_met();
  }
  if (!error.empty()) st["error_message"] = error;
  return st;
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
  } else if (job.runner && job.def) {
    j = engine_json(*job.def, *job.runner);
  } else {
    j = json::object();
  }
  j["id"] = job.id;
  j["state"] = std::string(job_status_name(job.status));
  j["priority"] = job.priority;
  if (!job.owner.empty()) j["owner"] = job.owner;
  j["spec"] = job.spec ? *job.spec : json(nullptr);
  j["plan"] = job.def ? plan_json(*job.def) : json(nullptr);
  if (job.runner) j["stop_rule"] = stop_rule_to_json(job.runner->rule());
  if (!job.error.empty()) j["error_message"] = job.error;
  if (job.status == JobStatus::running) {
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
                 {"compute_seconds", job.runner ? job.runner->state().compute_seconds : 0.0}};
  j["links"] = std::move(links);
  return j;
}

json summary_json(const JobSnapshot& job) {
  json j;
  j["id"] = job.id;
  j["state"] = std::string(job_status_name(job.status));
  j["kind"] = job.spec && job.spec->is_object() ? job.spec->value("kind", "") : std::string();
  j["priority"] = job.priority;
  if (!job.owner.empty()) j["owner"] = job.owner;
  j["created_at"] = time_json(job.created_at);
  if (job.runner) {
    const JobState& s = job.runner->state();
    j["samples"] = s.samples;
    j["passes"] = s.passes;
    if (!s.channels.empty() && s.channels[0].n > 0) {
      const Estimate e = job.runner->headline();  // an image job's mean radiance, else channel 0
      j["mean"] = std::isfinite(e.mean) ? json(e.mean) : json(nullptr);
      j["std_error"] = std::isfinite(e.std_error) ? json(e.std_error) : json(nullptr);
    }
    j["stop_reason"] = std::string(stop_reason_name(job.runner->stop_reason()));
  }
  if (!job.error.empty()) j["error_message"] = job.error;
  return j;
}

}  // namespace tally
