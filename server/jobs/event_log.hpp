#pragma once
// Per-job log of published events with a bounded replay buffer. Ids are
// monotonic per job and across restarts: id = epoch * 10^9 + sequence, where the
// epoch counts server starts (kept by the store). A client resuming with a
// Last-Event-ID older than the buffer (or from an earlier epoch) gets a fresh
// snapshot instead of the lost events.
#include <cstdint>
#include <deque>
#include <functional>
#include <mutex>
#include <string>
#include <vector>

namespace tally {

struct Event {
  uint64_t id = 0;
  std::string type;  // progress | state | tile | end | shutdown | preempted
  std::string data;  // one line of JSON
};

class EventLog {
 public:
  static constexpr uint64_t kEpochStride = 1'000'000'000ULL;

  explicit EventLog(uint64_t epoch = 1, size_t capacity = 1024);

  uint64_t append(std::string type, std::string data);
  // No more events will come (server shutdown); wakes every waiter.
  void close();

  struct Read {
    std::vector<Event> events;
    bool gap = false;  // events after `after` were evicted (or `after` is unknown)
    bool closed = false;
  };
  Read read_after(uint64_t after, size_t max_events = 256) const;

  // Stores `wake` to be called once an event after `after` exists or the log is
  // closed. Returns false (and does not store it) if that is already the case.
  bool wait(uint64_t after, std::function<void()> wake);

  uint64_t last_id() const;
  uint64_t first_id() const { return base_ + 1; }  // first id of this epoch
  bool closed() const;

 private:
  mutable std::mutex mu_;
  uint64_t base_;
  uint64_t next_;
  size_t capacity_;
  std::deque<Event> buffer_;
  bool closed_ = false;
  std::vector<std::function<void()>> waiters_;
};

}  // namespace tally
