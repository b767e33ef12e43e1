#pragma once
// A flag that ends what a credential opened: set when a token is revoked (SIGHUP
// reload without it) or a browser session logs out. Event streams subscribe a waker
// so a parked stream notices at once instead of at its next event.
#include <atomic>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>

#include "server/http/event_stream.hpp"

namespace tally {

class Revocation {
 public:
  bool revoked() const { return revoked_.load(std::memory_order_acquire); }
  // Sets the flag and calls every subscribed waker (outside the lock).
  void revoke();
  // `wake` runs once when revoked (at once if already). Returns a key for unsubscribe.
  uint64_t subscribe(std::function<void()> wake);
  void unsubscribe(uint64_t key);

 private:
  std::atomic<bool> revoked_{false};
  std::mutex mu_;
  uint64_t next_ = 1;
  std::map<uint64_t, std::function<void()>> wakers_;
};

// Wraps an event stream so it ends (after what is already out) once any of its
// revocations fires. Thread-safety: as EventStream (one session polls it).
class RevocableStream final : public EventStream {
 public:
  RevocableStream(std::shared_ptr<EventStream> inner, std::shared_ptr<Revocation> a, std::shared_ptr<Revocation> b);
  ~RevocableStream() override;
  bool poll(std::string& out) override;
  void on_ready(std::function<void()> wake) override;
  std::string heartbeat() const override { return inner_->heartbeat(); }

 private:
  bool revoked() const;
  struct Waker;
  std::shared_ptr<EventStream> inner_;
  std::shared_ptr<Revocation> a_, b_;
  std::shared_ptr<Waker> waker_;
  uint64_t key_a_ = 0, key_b_ = 0;
};

// The stream a principal may hold: wrapped when its credentials can be revoked.
std::shared_ptr<EventStream> revocable(std::shared_ptr<EventStream> inner, std::shared_ptr<Revocation> principal,
                                       std::shared_ptr<Revocation> session);

}  // namespace tally
