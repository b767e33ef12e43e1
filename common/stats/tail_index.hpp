#pragma once
// Heavy-tail detection with the Hill estimator of the tail index alpha, computed on
// the largest |sample| values: P(|X| > t) ~ t^-alpha. alpha <= 2 means the variance
// is infinite, so the standard error (and any interval built on it) cannot be
// trusted however many samples are taken; e.g. f = 1/sqrt(x) under uniform sampling
// has alpha = 2 exactly.
#include <cstddef>
#include <cstdint>
#include <optional>
#include <vector>

namespace tally {

class TailTracker {
 public:
  explicit TailTracker(size_t capacity = 512) : capacity_(capacity) {}

  // Keeps the `capacity` largest magnitudes offered. O(1) for values below the kept
  // minimum, which is almost every sample.
  void offer(double magnitude) {
    // Fast path, inlined into sampling loops: almost every value is below the kept minimum.
    if (heap_.size() == capacity_ && !(magnitude > heap_.front())) return;
    offer_slow(magnitude);
  }
  void merge(const TailTracker& other);
  // Values at or below this are not kept (hoist it out of loops; it only rises).
  double threshold() const {
    return heap_.size() < capacity_ ? 0.0 : heap_.front();
  }
  // Largest kept values, descending.
  std::vector<double> sorted_values() const;
  const std::vector<double>& heap() const { return heap_; }
  void assign(std::vector<double> values);  // from a checkpoint
  size_t capacity() const { return capacity_; }

  // Hill estimate from the top k+1 values, k = min(capacity - 1, n_total / 50);
  // nullopt when fewer than 100 tail values are available.
  std::optional<double> hill_alpha(uint64_t n_total) const;

  // The warning rule: alpha below 2.3 (the infinite-variance boundary is 2; the
  // margin covers the estimator's spread, sd ~ alpha / sqrt(k)).
  static constexpr double kWarnBelow = 2.3;

 private:
  void offer_slow(double magnitude);
  size_t capacity_;
  std::vector<double> heap_;  // min-heap of the largest magnitudes
};

}  // namespace tally
