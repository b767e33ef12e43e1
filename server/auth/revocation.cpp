#include "server/auth/revocation.hpp"

#include <vector>

namespace tally {

void Revocation::revoke() {
  std::vector<std::function<void()>> wake;
  {
    std::lock_guard lock(mu_);
    revoked_.store(true, std::memory_order_release);
    for (auto& [k, w] : wakers_) wake.push_back(std::move(w));
    wakers_.clear();
  }
  for (auto& w : wake) w();
}

uint64_t Revocation::subscribe(std::function<void()> wake) {
  {
    std::lock_guard lock(mu_);
    if (!revoked()) {
      const uint64_t k = next_++;
      wakers_.emplace(k, std::move(wake));
      return k;
    }
  }
  wake();
  return 0;
}

void Revocation::unsubscribe(uint64_t key) {
  std::lock_guard lock(mu_);
  wakers_.erase(key);
}

// The session's current waker; the revocations hold this (not the session) so a
// stream that is gone costs nothing when its token is revoked later.
struct RevocableStream::Waker {
  std::mutex mu;
  std::function<void()> wake;
  bool fired = false;  // revoked before anyone parked
  void fire() {
    std::function<void()> w;
    {
      std::lock_guard lock(mu);
      fired = true;
      w = std::move(wake);
      wake = nullptr;
    }
    if (w) w();
  }
};

RevocableStream::RevocableStream(std::shared_ptr<EventStream> inner, std::shared_ptr<Revocation> a,
                                 std::shared_ptr<Revocation> b)
    : inner_(std::move(inner)), a_(std::move(a)), b_(std::move(b)), waker_(std::make_shared<Waker>()) {
  std::weak_ptr<Waker> weak = waker_;
  auto fire = [weak] {
    if (auto w = weak.lock()) w->fire();
  };
  if (a_) key_a_ = a_->subscribe(fire);
  if (b_) key_b_ = b_->subscribe(fire);
}

RevocableStream::~RevocableStream() {
  if (a_ && key_a_) a_->unsubscribe(key_a_);
  if (b_ && key_b_) b_->unsubscribe(key_b_);
}

bool RevocableStream::revoked() const { return (a_ && a_->revoked()) || (b_ && b_->revoked()); }

bool RevocableStream::poll(std::string& out) {
  if (revoked()) return false;  // the credential is gone: end the stream now
  return inner_->poll(out);
}

void RevocableStream::on_ready(std::function<void()> wake) {
  // Whichever comes first (an event or a revocation) wakes the session once.
  auto once = std::make_shared<std::atomic<bool>>(false);
  auto shared = std::make_shared<std::function<void()>>(std::move(wake));
  auto call = [once, shared] {
    if (!once->exchange(true)) (*shared)();
  };
  bool fired;
  {
    std::lock_guard lock(waker_->mu);
    fired = waker_->fired;
    if (!fired) waker_->wake = call;
  }
  if (fired || revoked()) return call();
  inner_->on_ready(call);
}

std::shared_ptr<EventStream> revocable(std::shared_ptr<EventStream> inner, std::shared_ptr<Revocation> principal,
                                       std::shared_ptr<Revocation> session) {
  if (!principal && !session) return inner;
  return std::make_shared<RevocableStream>(std::move(inner), std::move(principal), std::move(session));
}

}  // namespace tally
