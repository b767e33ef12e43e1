#pragma once
// The base of a deterministic rule's kernel (cubature, the cone rule): the whole rule
// runs in one block of one pass; its one "sample" has channels c = component c's value
// and m + c = its error estimate or bound, for m components. The headline is component
// 0's value with no standard error; the error summary is the worst component's error
// (not a confidence half-width). Thread-safety: as Kernel (const, no state of its own).
#include <cmath>
#include <limits>
#include <optional>

#include "common/engine/job_state.hpp"
#include "common/engine/kernel.hpp"
#include "common/integrate/integration_counters.hpp"

namespace tally {

class RuleKernelBase : public Kernel {
 public:
  explicit RuleKernelBase(size_t components) : m_(components) {}

  size_t channel_count() const final { return 2 * m_; }
  std::span<const std::string_view> counter_names() const final { return integration_counter_names(); }
  std::vector<std::string> warnings(const JobState& st) const final { return integration_counter_warnings(st); }
  PassSchedule schedule() const final { return {1, 1, 1}; }

  void run_block(const Block& b, BlockResult& out) const final {
    out.first_channel = 0;
    out.tallies.assign(channel_count(), Tally{});
    if (b.first_sample > 0) return;  // deterministic: a second "sample" would repeat the first
    run_rule(out);
  }

  std::optional<Headline> headline(const JobState& st) const final {
    if (st.channels.size() != channel_count() || st.channels[0].n == 0) return std::nullopt;
    return Headline{st.channels[0].mean, std::numeric_limits<double>::quiet_NaN()};
  }

  ErrorSummary error_summary(const JobState& st, double) const final {
    ErrorSummary e;
    e.abs_error = e.rel_error = std::numeric_limits<double>::infinity();
    e.sigma = std::numeric_limits<double>::quiet_NaN();
    if (st.channels.size() != channel_count() || st.channels[0].n == 0) return e;
    e.mean = st.channels[0].mean;
    for (size_t c = 0; c < m_; ++c) {
      const double v = st.channels[c].mean, err = st.channels[m_ + c].mean;
      const double rel = v != 0.0 ? err / std::fabs(v) : (err == 0.0 ? 0.0 : std::numeric_limits<double>::infinity());
      if (c == 0 || err > e.abs_error) {
        e.abs_error = err;
        e.mean = v;
      }
      if (c == 0 || rel > e.rel_error) e.rel_error = rel;
    }
    return e;
  }

 protected:
  // Runs the rule and adds each component's value to out.tallies[c] and its error to
  // out.tallies[m + c] (already sized); on a fault sets out.fault, on an abandoned block
  // returns early (the result is dropped).
  virtual void run_rule(BlockResult& out) const = 0;

  size_t m_;
};

}  // namespace tally
