#include "server/auth/token_bucket.hpp"

#include <algorithm>

namespace tally {

double TokenBucket::take(double now) {
  if (now > last_) {
    tokens_ = std::min(burst_, tokens_ + (now - last_) * rate_);
    last_ = now;
  }
  if (tokens_ >= 1.0) {
    tokens_ -= 1.0;
    return 0.0;
  }
  return (1.0 - tokens_) / rate_;
}

void TokenBucket::reconfigure(double rate, double burst) {
  rate_ = rate;
  burst_ = burst;
  tokens_ = std::min(tokens_, burst_);
}

}  // namespace tally
