#include "server/jobs/event_log.hpp"

namespace tally {

EventLog::EventLog(uint64_t epoch, size_t capacity)
    : base_(epoch * kEpochStride), next_(epoch * kEpochStride + 1), capacity_(capacity > 0 ? capacity : 1) {}

uint64_t EventLog::append(std::string type, std::string data) {
  std::vector<std::function<void()>> wake;
  uint64_t id;
  {
    std::lock_guard lock(mu_);
    id = next_++;
    buffer_.push_back(Event{id, std::move(type), std::move(data)});
    if (buffer_.size() > capacity_) buffer_.pop_front();
    wake.swap(waiters_);
  }
  for (auto& w : wake) w();
  return id;
}

void EventLog::close() {
  std::vector<std::function<void()>> wake;
  {
    std::lock_guard lock(mu_);
    closed_ = true;
    wake.swap(waiters_);
  }
  for (auto& w : wake) w();
}

EventLog::Read EventLog::read_after(uint64_t after, size_t max_events) const {
  std::lock_guard lock(mu_);
  Read r;
  r.closed = closed_;
  const uint64_t last = next_ - 1;
  if (after > last || after < base_) {
    // From the future or from an earlier epoch: nothing we can replay.
    r.gap = true;
    return r;
  }
  const uint64_t oldest = buffer_.empty() ? next_ : buffer_.front().id;
  if (after + 1 < oldest) r.gap = true;
  if (r.gap) return r;
  for (size_t i = static_cast<size_t>(after + 1 - oldest); i < buffer_.size() && r.events.size() < max_events; ++i) {
    r.events.push_back(buffer_[i]);
  }
  return r;
}

bool EventLog::wait(uint64_t after, std::function<void()> wake) {
  std::lock_guard lock(mu_);
  if (closed_ || next_ - 1 > after) return false;
  waiters_.push_back(std::move(wake));
  return true;
}

uint64_t EventLog::last_id() const {
  std::lock_guard lock(mu_);
  return next_ - 1;
}

bool EventLog::closed() const {
  std::lock_guard lock(mu_);
  return closed_;
}

}  // namespace tally
