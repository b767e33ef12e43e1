#pragma once
// Rate limits on browser logins (POST /v1/session): a token bucket per principal and one
// per client address. Without them one reader's 10,050 logins in 7.7 s filled the
// session table and evicted the admin's session (issue 27 N8); the per-address bucket
// also slows token guessing, since it is taken before the token is looked at.
// Bounded: at most kMaxBuckets addresses are tracked; idle buckets (full again) are
// dropped first. Thread-safe.
#include <cstddef>
#include <map>
#include <mutex>
#include <string>
#include <string_view>

#include "server/auth/token_bucket.hpp"

namespace tally {

struct LoginRate {
  double per_second;
  double burst;
};

class LoginLimiter {
 public:
  // A principal: 10 logins at once, then one every 6 s; an address: 20, then 1 a second
  // (behind a reverse proxy every client shares the proxy's address).
  static constexpr LoginRate kPerPrincipal{1.0 / 6.0, 10};
  static constexpr LoginRate kPerAddress{1.0, 20};
  static constexpr size_t kMaxBuckets = 4096;

  explicit LoginLimiter(LoginRate per_principal = kPerPrincipal, LoginRate per_address = kPerAddress)
      : principal_rate_(per_principal), address_rate_(per_address) {}

  // 0: go on (a token was taken); else seconds until a login may be tried (Retry-After).
  // An empty address (a request without a socket) is not limited by address.
  double take_address(std::string_view address, double now);
  double take_principal(std::string_view principal, double now);

 private:
  struct Entry {
    TokenBucket bucket;
    double last = 0;
  };
  double take(std::map<std::string, Entry, std::less<>>& buckets, const LoginRate& rate, std::string_view key,
              double now);

  LoginRate principal_rate_, address_rate_;
  std::mutex mu_;
  std::map<std::string, Entry, std::less<>> by_principal_, by_address_;
};

}  // namespace tally
