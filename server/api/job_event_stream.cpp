#include "server/api/job_event_stream.hpp"

#include <charconv>

#include <fmt/format.h>

#include "common/protocol/job_json.hpp"
#include "server/api/route_support.hpp"
#include "server/jobs/job_manager.hpp"

namespace tally {

std::optional<uint64_t> parse_last_event_id(std::string_view s) { return parse_u64(s); }


std::string format_event(const Event& e, StreamFormat format) {
  if (format == StreamFormat::ndjson) {
    return fmt::format("{{\"id\":{},\"event\":\"{}\",\"data\":{}}}\n", e.id, e.type, e.data);
  }
  return fmt::format("id: {}\nevent: {}\ndata: {}\n\n", e.id, e.type, e.data);
}

std::vector<Event> snapshot_events(const JobSnapshot& job) {
  const auto dump = [](const nlohmann::json& j) {
    return j.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
  };
  const uint64_t id = job.last_event_id;
  std::vector<Event> out;
  // A job whose state is not in memory (queued, or finished and on disk) shows the
  // figures kept when it left (RunFacts): the same bytes the runner would give.
  const auto state_event = [&](bool end) {
    return job.runner ? state_event_json(job.status, job.runner.get(), job.error, end)
                      : state_event_json(job.status, job.facts.get(), job.error, end);
  };
  out.push_back(Event{id, "state", dump(state_event(false))});
  if (job.runner && job.runner->state().passes > 0) {
    out.push_back(Event{id, "progress", dump(progress_event_json(*job.runner))});
  } else if (!job.runner && job.facts && !job.facts->progress_event.empty()) {
    out.push_back(Event{id, "progress", job.facts->progress_event});
  }
  if (is_terminal(job.status)) out.push_back(Event{id, "end", dump(state_event(true))});
  return out;
}

JobEventStream::JobEventStream(std::shared_ptr<Job> job, const JobManager& manager, StreamFormat format,
                               std::optional<uint64_t> last_event_id)
    : job_(std::move(job)), manager_(manager), format_(format) {
  if (last_event_id) {
    const EventLog::Read r = job_->events().read_after(*last_event_id, 0);
    if (!r.gap) {
      cursor_ = *last_event_id;
      const bool terminal = is_terminal(manager_.snapshot(*job_).status);
      // Resuming after the end of a finished job: repeat the end, don't hang.
      if (terminal && job_->events().last_id() == cursor_) take_snapshot();
      return;
    }
  }
  take_snapshot();
}

void JobEventStream::take_snapshot() {
  pending_ = snapshot_events(manager_.snapshot(*job_));
  cursor_ = pending_.empty() ? job_->events().last_id() : pending_.front().id;
}

bool JobEventStream::emit(const Event& e, std::string& out) {
  out += format_event(e, format_);
  if (e.type == "end" || e.type == "shutdown") {
    ended_ = true;
    return false;
  }
  return true;
}

bool JobEventStream::poll(std::string& out) {
  if (ended_) return false;
  if (!pending_.empty()) {
    std::vector<Event> p = std::move(pending_);
    pending_.clear();
    for (const Event& e : p) {
      if (!emit(e, out)) return false;
    }
  }
  for (int round = 0; round < 2; ++round) {
    const EventLog::Read r = job_->events().read_after(cursor_, 256);
    if (r.gap) {
      // This watcher fell behind the replay buffer: start over from a snapshot.
      take_snapshot();
      std::vector<Event> p = std::move(pending_);
      pending_.clear();
      for (const Event& e : p) {
        if (!emit(e, out)) return false;
      }
      continue;
    }
    for (const Event& e : r.events) {
      cursor_ = e.id;
      if (!emit(e, out)) return false;
    }
    if (r.events.empty() && r.closed) {
      ended_ = true;
      return false;
    }
    break;
  }
  return true;
}

void JobEventStream::on_ready(std::function<void()> wake) {
  if (ended_ || !pending_.empty()) {
    wake();
    return;
  }
  if (!job_->events().wait(cursor_, wake)) wake();
}

std::string JobEventStream::heartbeat() const { return format_ == StreamFormat::sse ? ": keep-alive\n\n" : ""; }

}  // namespace tally
