#include "server/auth/login_limiter.hpp"

#include <iterator>

namespace tally {

double LoginLimiter::take(std::map<std::string, Entry, std::less<>>& buckets, const LoginRate& rate,
                          std::string_view key, double now) {
  auto it = buckets.find(key);
  if (it == buckets.end()) {
    if (buckets.size() >= kMaxBuckets) {
      // A bucket untouched for burst / rate seconds is full again: dropping it changes nothing.
      const double refill = rate.burst / rate.per_second;
      for (auto e = buckets.begin(); e != buckets.end();) {
        e = now - e->second.last >= refill ? buckets.erase(e) : std::next(e);
      }
      if (buckets.size() >= kMaxBuckets) return 1.0 / rate.per_second;  // every tracked caller is busy
    }
    it = buckets.emplace(std::string(key), Entry{TokenBucket(rate.per_second, rate.burst, now), now}).first;
  }
  it->second.last = now;
  return it->second.bucket.take(now);
}

double LoginLimiter::take_address(std::string_view address, double now) {
  if (address.empty()) return 0.0;
  std::lock_guard lock(mu_);
  return take(by_address_, address_rate_, address, now);
}

double LoginLimiter::take_principal(std::string_view principal, double now) {
  std::lock_guard lock(mu_);
  return take(by_principal_, principal_rate_, principal, now);
}

}  // namespace tally
