#include "common/stats/tail_index.hpp"

#include <algorithm>
#include <cmath>
#include <functional>

namespace tally {

void TailTracker::offer_slow(double magnitude) {
  if (!(magnitude > 0.0) || !std::isfinite(magnitude)) return;
  if (heap_.size() < capacity_) {
    heap_.push_back(magnitude);
    std::push_heap(heap_.begin(), heap_.end(), std::greater<>());
  } else if (magnitude > heap_.front()) {
    std::pop_heap(heap_.begin(), heap_.end(), std::greater<>());
    heap_.back() = magnitude;
    std::push_heap(heap_.begin(), heap_.end(), std::greater<>());
  }
}

void TailTracker::merge(const TailTracker& other) {
  for (double v : other.heap_) offer(v);
}

std::vector<double> TailTracker::sorted_values() const {
  std::vector<double> v = heap_;
  std::sort(v.begin(), v.end(), std::greater<>());
  return v;
}

void TailTracker::assign(std::vector<double> values) {
  heap_.clear();
  for (double v : values) offer(v);
}

std::optional<double> TailTracker::hill_alpha(uint64_t n_total) const {
  const std::vector<double> v = sorted_values();
  if (v.size() < 101) return std::nullopt;
  const size_t k = std::min<size_t>(v.size() - 1, static_cast<size_t>(n_total / 50));
  if (k < 100) return std::nullopt;
  const double threshold = v[k];
  double sum = 0.0;
  for (size_t i = 0; i < k; ++i) sum += std::log(v[i] / threshold);
  if (!(sum > 0.0)) return std::nullopt;
  return static_cast<double>(k) / sum;
}

}  // namespace tally
