#pragma once
// GET /v1/jobs/{id}/events as Server-Sent Events or NDJSON. A new watcher starts
// with a snapshot (state + progress); a resuming one (Last-Event-ID) gets the
// events it missed from the job's replay buffer, or a fresh snapshot when they
// are gone (JobManager::watch_snapshot: cached per job version, so a watcher that
// lags every pass costs little). The stream ends after `end` (job finished) or `shutdown`.
#include <cstdint>
#include <memory>
#include <optional>
#include <string_view>
#include <vector>

#include "server/jobs/event_log.hpp"
#include "server/http/event_stream.hpp"

namespace tally {

class Job;
class JobManager;
struct JobSnapshot;

enum class StreamFormat { sse, ndjson };

// The event id a client resumes after (Last-Event-ID header or last_event_id query
// parameter): a decimal uint64, surrounding spaces allowed; nullopt otherwise.
std::optional<uint64_t> parse_last_event_id(std::string_view text);

std::string format_event(const Event& e, StreamFormat format);

class JobEventStream final : public EventStream {
 public:
  JobEventStream(std::shared_ptr<Job> job, const JobManager& manager, StreamFormat format,
                 std::optional<uint64_t> last_event_id);
  bool poll(std::string& out) override;
  void on_ready(std::function<void()> wake) override;
  std::string heartbeat() const override;

 private:
  void take_snapshot();
  // Appends `e`; returns false if it ends the stream.
  bool emit(const Event& e, std::string& out);

  std::shared_ptr<Job> job_;
  const JobManager& manager_;
  StreamFormat format_;
  std::vector<Event> pending_;
  uint64_t cursor_ = 0;
  bool ended_ = false;
};

}  // namespace tally
