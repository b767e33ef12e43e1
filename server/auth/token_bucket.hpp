#pragma once
// A token bucket (rate r per second, capacity b): take() spends one token or says
// how long until one is available. Not thread-safe; the owner locks.
namespace tally {

class TokenBucket {
 public:
  TokenBucket(double rate, double burst, double now) : rate_(rate), burst_(burst), tokens_(burst), last_(now) {}
  // 0 if a token was taken; else seconds until the next one (nothing taken).
  double take(double now);
  void reconfigure(double rate, double burst);

 private:
  double rate_, burst_, tokens_, last_;
};

}  // namespace tally
