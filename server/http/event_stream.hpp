#pragma once
// A response body produced over time (Server-Sent Events or NDJSON). The session
// pulls output with poll() and parks with on_ready() until there is more, so a
// watcher costs no thread and nothing while the job computes.
#include <functional>
#include <string>

namespace tally {

class EventStream {
 public:
  virtual ~EventStream() = default;
  // Appends whatever output is ready to `out`. Returns false once the stream has
  // ended (its final output, if any, is in `out`).
  virtual bool poll(std::string& out) = 0;
  // Calls `wake` once, from any thread, when poll() may have more to give;
  // immediately if it already has.
  virtual void on_ready(std::function<void()> wake) = 0;
  // Keep-alive text for an idle stream ("" = none).
  virtual std::string heartbeat() const { return {}; }
};

}  // namespace tally
