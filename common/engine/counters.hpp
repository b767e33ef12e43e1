#pragma once
// Event counters that prove what a job simulated (rays by kind, evaluations, rejected
// proposals...). The engine keeps them as a plain indexed array: each kernel declares
// its own counters (Kernel::counter_names(), typically an enum of its own kind), so the
// engine knows no job kind. Adding one up in a hot loop is an array increment.
#include <algorithm>
#include <cstdint>
#include <string_view>
#include <type_traits>
#include <vector>

namespace tally {

struct Counters {
  // The most counters a kernel may declare (a bound for decoding untrusted bytes).
  static constexpr size_t kMaxCounters = 64;

  std::vector<uint64_t> values;  // indexed by the kernel's counter ids

  void add(size_t i, uint64_t k = 1) {
    if (i >= values.size()) values.resize(i + 1);
    values[i] += k;
  }
  template <class E>
    requires std::is_enum_v<E>
  void add(E e, uint64_t k = 1) {
    add(static_cast<size_t>(e), k);
  }
  uint64_t operator[](size_t i) const noexcept { return i < values.size() ? values[i] : 0; }
  template <class E>
    requires std::is_enum_v<E>
  uint64_t operator[](E e) const noexcept {
    return (*this)[static_cast<size_t>(e)];
  }
  void merge(const Counters& o) {
    if (o.values.size() > values.size()) values.resize(o.values.size());
    for (size_t i = 0; i < o.values.size(); ++i) values[i] += o.values[i];
  }
  // Equal when every counter is (a missing trailing counter counts as zero).
  friend bool operator==(const Counters& a, const Counters& b) noexcept {
    const size_t n = std::max(a.values.size(), b.values.size());
    for (size_t i = 0; i < n; ++i) {
      if (a[i] != b[i]) return false;
    }
    return true;
  }
};

}  // namespace tally
