#include "common/engine/job_runner.hpp"

#include "common/engine/check.hpp"
#include "common/engine/forecast.hpp"

#include <algorithm>
#include <cmath>
#include <fmt/format.h>
#include <limits>
#include <stdexcept>

#include "common/stats/confidence.hpp"

namespace tally {

namespace {
constexpr double kInf = std::numeric_limits<double>::infinity();

// forecast() for a runner: with per-component targets, the error target's forecast is the
// samples the component furthest from its own target needs, n * ratio^2 (its half-width
// falls as 1/sqrt(n)), no earlier than min_samples.
Forecast runner_forecast(const Kernel& kernel, const JobState& st, const StopRule& rule, const JobCaps& caps,
                         const ErrorSummary& err, double rate) {
  Forecast f = forecast(rule, caps, err, st.samples, st.compute_seconds, rate);
  if (!rule.component_targets || st.samples < 2) return f;
  const std::vector<ComponentError> errors = kernel.component_errors(st, rule.confidence);
  double worst = errors.empty() ? kInf : 0.0;
  for (size_t c = 0; c < errors.size(); ++c) worst = std::max(worst, component_target_ratio(rule, c, errors[c]));
  if (!std::isfinite(worst)) return f;
  const double n = static_cast<double>(st.samples);
  f.samples_needed = n * worst * worst;
  const double fires = std::max(f.samples_needed, static_cast<double>(rule.min_samples));
  f.error_target = RuleForecast{fires, rate > 0 ? std::max(0.0, fires - n) / rate : kInf};
  return f;
}

std::vector<std::string> names_of(const Kernel& k) {
  const auto names = k.counter_names();
  TALLY_CHECK_LE(names.size(), Counters::kMaxCounters);
  return {names.begin(), names.end()};
}

// A restored state's counters in the kernel's layout, matched by name (a checkpoint of
// an older layout, e.g. version 2's fixed list, still resumes). A non-zero counter the
// kernel does not declare means the checkpoint belongs to another job.
void adopt_counter_layout(JobState& s, const std::vector<std::string>& names) {
  if (s.counter_names == names) {
    s.counters.values.resize(names.size());
    return;
  }
  Counters mapped;
  mapped.values.assign(names.size(), 0);
  for (size_t i = 0; i < s.counters.values.size(); ++i) {
    const uint64_t v = s.counters.values[i];
    const std::string name = i < s.counter_names.size() ? s.counter_names[i] : fmt::format("#{}", i);
    const auto it = std::find(names.begin(), names.end(), name);
    if (it != names.end()) {
      mapped.values[static_cast<size_t>(it - names.begin())] += v;
    } else if (v != 0) {
      throw std::invalid_argument(
          fmt::format("checkpoint does not match the job: it counts {} ({}), which this job does not", name, v));
    }
  }
  s.counters = std::move(mapped);
  s.counter_names = names;
}
}  // namespace

JobRunner::JobRunner(std::shared_ptr<const Kernel> kernel, StopRule rule, JobCaps caps)
    : kernel_(std::move(kernel)), rule_(rule), caps_(caps) {
  state_.channels.assign(kernel_->channel_count(), Tally{});
  state_.sums.assign(kernel_->sum_count(), 0.0f);
  state_.partition_samples.assign(kernel_->partition_count(), 0);
  state_.counter_names = names_of(*kernel_);
  state_.counters.values.assign(state_.counter_names.size(), 0);
  summarize_error();
}

JobRunner::JobRunner(std::shared_ptr<const Kernel> kernel, StopRule rule, JobCaps caps,
                     JobState restored)
    : kernel_(std::move(kernel)), rule_(rule), caps_(caps), state_(std::move(restored)) {
  const auto fits = [&] {
    return state_.channels.size() == kernel_->channel_count() && state_.sums.size() == kernel_->sum_count() &&
           state_.partition_samples.size() == kernel_->partition_count();
  };
  if (!fits() && kernel_->upgrade_state(state_) && !fits()) {
    throw std::logic_error("Kernel::upgrade_state left a state that does not fit the kernel");
  }
  if (!fits()) {
    throw std::invalid_argument(fmt::format(
        "checkpoint does not match the job: {} channels / {} sums / {} partitions, expected {} / {} / {} (it was "
        "written by results version {}; this build is version {})",
        state_.channels.size(), state_.sums.size(), state_.partition_samples.size(), kernel_->channel_count(),
        kernel_->sum_count(), kernel_->partition_count(), state_.results_version, kResultsVersion));
  }
  adopt_counter_layout(state_, names_of(*kernel_));
  summarize_error();
  if (state_.fault) {
    reason_ = StopReason::failed;
    error_ = state_.fault->message;
  } else {
    evaluate_stop();
  }
}

uint64_t JobRunner::next_pass_samples(const JobState& st) const {
  const PassSchedule s = kernel_->schedule();
  const uint64_t shift = std::min<uint64_t>(st.passes, 40);
  uint64_t n = std::min(s.max_pass_samples, s.first_pass_samples << shift);
  if (n == 0) n = 1;
  // Do not overshoot hard limits.
  uint64_t limit = caps_.max_samples;
  if (rule_.max_samples > 0) limit = std::min(limit, rule_.max_samples);
  if (limit > st.samples) n = std::min(n, limit - st.samples);
  // Aim an error-target pass at the predicted need (deterministic: depends on the
  // state only), with 10% headroom, never below one block. (Not for plan_ahead's
  // counts-only state: plan_ahead plans nothing for a rule with an error target.)
  if (rule_.has_error_target() && st.samples >= rule_.min_samples && !heavy_tail()) {
    if (auto p = prediction(); p && std::isfinite(p->samples_remaining)) {
      const double want = std::max(1.1 * p->samples_remaining, static_cast<double>(s.block_samples));
      if (want < static_cast<double>(n)) n = static_cast<uint64_t>(want);
    }
  }
  // With a time budget, a pass should not run far past it.
  if (rule_.time_budget_s > 0 && st.compute_seconds > 0 && st.samples > 0) {
    const double rate = samples_per_second();
    const double left = std::max(0.0, rule_.time_budget_s - st.compute_seconds);
    const double fit = std::max(static_cast<double>(s.block_samples), rate * left * 1.05);
    if (fit < static_cast<double>(n)) n = static_cast<uint64_t>(fit);
  }
  if (s.sample_quantum > 1) {
    const uint64_t q = s.sample_quantum;
    const uint64_t up = (std::max<uint64_t>(n, 1) + q - 1) / q * q;
    if (limit <= st.samples || up <= limit - st.samples) n = up;
  }
  return std::max<uint64_t>(n, 1);
}

std::vector<Block> JobRunner::blocks_after(const JobState& st, uint64_t n) const {
  const uint64_t block = std::max<uint64_t>(1, kernel_->schedule().block_samples);
  std::vector<Block> blocks;
  uint64_t index = 0;
  for (uint32_t p : kernel_->active_partitions(st)) {
    const uint64_t first = st.partition_samples.at(p);
    for (uint64_t off = 0; off < n; off += block) {
      blocks.push_back(Block{index++, first + off, std::min(block, n - off), p});
    }
  }
  return blocks;
}

std::vector<Block> JobRunner::plan_pass() {
  if (finished()) return {};
  TALLY_CHECK_MSG(pending_.empty(), "plan_pass called twice without commit_pass");
  const uint64_t n = next_pass_samples(state_);
  pass_input_ = kernel_->pass_input(state_);
  pending_ = blocks_after(state_, n);
  groups_ = tally::result_groups(pending_, kernel_->schedule().group_blocks);
  pending_samples_ = n;
  if (pending_.empty()) {
    // Nothing left to refine (adaptive sampling converged everywhere).
    reason_ = StopReason::error_target;
  }
  return pending_;
}

std::optional<JobState> JobRunner::counts_after(const JobState& s, const std::vector<Block>& pass,
                                                uint64_t samples) const {
  JobState next;
  next.passes = s.passes + 1;
  next.samples = s.samples + samples;
  next.partition_samples = s.partition_samples;
  for (const Block& b : pass) next.partition_samples.at(b.partition) += b.sample_count;
  // evaluate_stop's rules that counts decide: the job ends after this pass.
  if (rule_.max_samples > 0 && next.samples >= rule_.max_samples) return std::nullopt;
  if (next.samples >= caps_.max_samples) return std::nullopt;
  return next;
}

std::optional<std::vector<Block>> JobRunner::plan_ahead(bool* followed) const {
  if (followed) *followed = false;
  if (finished() || pending_.empty() || groups_merged() > 0 || !kernel_->plans_from_counts()) return std::nullopt;
  if (rule_.has_error_target() || rule_.time_budget_s > 0) return std::nullopt;
  // The counts the pending pass leaves (commit_pass adds exactly these).
  const std::optional<JobState> next = counts_after(state_, pending_, pending_samples_);
  if (!next) return std::nullopt;
  const uint64_t n = next_pass_samples(*next);
  std::vector<Block> blocks = blocks_after(*next, n);
  if (blocks.empty()) return std::nullopt;
  if (followed) {
    const std::optional<JobState> after = counts_after(*next, blocks, n);
    *followed = after && !blocks_after(*after, next_pass_samples(*after)).empty();
  }
  return blocks;
}

void JobRunner::commit_pass(std::vector<BlockResult>&& results, double wall_seconds) {
  TALLY_CHECK_EQ(results.size(), pending_.size());  // one result per planned block
  commit_groups(combine_groups(std::move(results), groups_), wall_seconds);
}

void JobRunner::commit_groups(std::vector<BlockResult>&& given, double wall_seconds) {
  // Owned here, so the pass's results (for an image, as large as the state) are freed
  // as they are merged, not when the caller's vector goes: whatever follows the commit
  // (views, a checkpoint) has the state alone in memory.
  std::vector<BlockResult> results = std::move(given);
  TALLY_CHECK_EQ(results.size(), groups_.size());  // one result per result group
  for (BlockResult& r : results) merge_group(std::move(r));
  finish_pass(wall_seconds);
}

void JobRunner::merge_group(BlockResult&& given) {
  TALLY_CHECK_MSG(groups_merged() < groups_.size(), "result group {} of a pass of {}", groups_merged(), groups_.size());
  BlockResult r = std::move(given);
  TALLY_CHECK_LE(r.counters.values.size(), state_.counter_names.size());  // only ids the kernel declared
  if (kernel_->folds_passes()) {
    held_.push_back(std::move(r));
    return;
  }
  TALLY_CHECK_MSG(r.aux.empty(), "a result carries kernel accumulators (aux) but the kernel does not fold passes");
  merge_result(r, merged_++);
}

void JobRunner::merge_result(BlockResult& r, size_t group) {
  for (size_t c = 0; c < r.tallies.size(); ++c) {
    state_.channels.at(r.first_channel + c).merge(r.tallies[c]);
  }
  std::vector<Tally>().swap(r.tallies);
  TALLY_CHECK_LE(uint64_t{r.first_sum} + r.sums.size(), state_.sums.size());
  float* sums = state_.sums.data() + r.first_sum;  // added in double, rounded once (JobState::sums)
  for (size_t c = 0; c < r.sums.size(); ++c) sums[c] = static_cast<float>(static_cast<double>(sums[c]) + r.sums[c]);
  std::vector<double>().swap(r.sums);
  state_.counters.merge(r.counters);
  state_.tail.merge(r.tail);
  state_.weights.merge(r.weights);
  if (r.fault && !state_.fault) state_.fault = std::move(r.fault);
  const ResultGroup& g = groups_[group];
  for (size_t b = g.first; b < g.first + g.count; ++b) {
    state_.partition_samples[pending_[b].partition] += pending_[b].sample_count;
  }
}

void JobRunner::finish_pass(double wall_seconds) {
  if (kernel_->folds_passes()) {
    TALLY_CHECK_EQ(held_.size(), groups_.size());
    kernel_->fold_pass(pass_input_, held_, state_);
    for (BlockResult& r : held_) merge_result(r, merged_++);
    std::vector<BlockResult>().swap(held_);
  }
  TALLY_CHECK_MSG(merged_ == groups_.size(), "finish_pass after {} of {} result groups", merged_, groups_.size());
  state_.samples += pending_samples_;
  state_.passes += 1;
  state_.compute_seconds += wall_seconds;
  pending_.clear();
  groups_.clear();
  pending_samples_ = 0;
  merged_ = 0;
  summarize_error();
  push_trace();
  evaluate_stop();
}

void JobRunner::push_trace() {
  const ErrorSummary& e = error();
  const Tally& t0 = state_.channels.empty() ? Tally{} : state_.channels[0];
  TracePoint p{state_.compute_seconds, state_.samples, state_.channels.size() == 1 ? t0.mean : e.mean,
               state_.channels.size() == 1 ? t0.std_error() : e.sigma / std::sqrt(std::max<double>(1.0, static_cast<double>(state_.samples)))};
  auto& tr = state_.trace;
  tr.push_back(p);
  if (tr.size() > JobState::kMaxTrace) {
    // Thin the older half: keep every other point (the newest always stays).
    std::vector<TracePoint> thinned;
    thinned.reserve(tr.size() / 2 + 1);
    for (size_t i = 0; i + 1 < tr.size(); i += 2) thinned.push_back(tr[i]);
    thinned.push_back(tr.back());
    tr = std::move(thinned);
  }
}

void JobRunner::evaluate_stop() {
  if (reason_ == StopReason::cancelled || reason_ == StopReason::failed) return;
  reason_ = StopReason::none;
  if (state_.fault) {
    reason_ = StopReason::failed;
    error_ = state_.fault->message;
    return;
  }
  if (state_.samples == 0) return;
  if (target_met() && !heavy_tail()) {
    reason_ = StopReason::error_target;
  } else if (rule_.max_samples > 0 && state_.samples >= rule_.max_samples) {
    reason_ = StopReason::max_samples;
  } else if (rule_.time_budget_s > 0 && state_.compute_seconds >= rule_.time_budget_s) {
    reason_ = StopReason::time_budget;
  } else if (state_.samples >= caps_.max_samples || state_.compute_seconds >= caps_.max_seconds) {
    reason_ = StopReason::sample_cap;
  }
}

void JobRunner::cancel() {
  if (!finished()) reason_ = StopReason::cancelled;
  pending_.clear();
  groups_.clear();
  merged_ = 0;
  held_.clear();
}

void JobRunner::fail(std::string message) {
  reason_ = StopReason::failed;
  error_ = std::move(message);
  pending_.clear();
  groups_.clear();
  merged_ = 0;
  held_.clear();
}

void JobRunner::extend(const StopRule& rule) {
  TALLY_CHECK_MSG(reason_ != StopReason::failed, "a failed job cannot be extended");
  rule_ = rule;
  reason_ = StopReason::none;
  pending_.clear();
  groups_.clear();
  merged_ = 0;
  held_.clear();
  summarize_error();  // the confidence may have changed
  evaluate_stop();
}

Estimate JobRunner::estimate(size_t channel) const {
  const Tally& t = state_.channels.at(channel);
  Estimate e;
  e.n = t.n;
  e.mean = t.mean;
  e.variance = t.variance();
  e.std_error = t.std_error();
  e.rel_error = t.relative_error();
  e.confidence = rule_.confidence;
  const Interval ci = confidence_interval(t, rule_.confidence);
  e.ci_lo = ci.lo;
  e.ci_hi = ci.hi;
  return e;
}

Estimate JobRunner::headline() const {
  const auto h = kernel_->headline(state_);
  if (!h) return estimate(0);
  Estimate e;
  e.n = state_.samples;
  e.mean = h->mean;
  e.std_error = h->std_error;
  e.variance = h->std_error * h->std_error * static_cast<double>(std::max<uint64_t>(1, e.n));
  e.rel_error = h->mean != 0.0 ? h->std_error / std::fabs(h->mean) : kInf;
  e.confidence = rule_.confidence;
  // Many independent channels: the normal limit, unless the kernel says otherwise.
  const double z = critical_value(rule_.confidence, h->critical_n);
  e.ci_lo = h->mean - z * h->std_error;
  e.ci_hi = h->mean + z * h->std_error;
  return e;
}

double JobRunner::samples_per_second() const {
  return state_.compute_seconds > 0 ? static_cast<double>(state_.samples) / state_.compute_seconds
                                    : 0.0;
}

bool JobRunner::target_met() const {
  if (!rule_.has_error_target() || state_.samples < rule_.min_samples) return false;
  if (rule_.component_targets) {  // every component its own target
    return every_component_met(rule_, kernel_->component_errors(state_, rule_.confidence));
  }
  const ErrorSummary e = error();
  if (rule_.abs_error > 0 && e.abs_error <= rule_.abs_error) return true;
  if (rule_.rel_error > 0 && e.rel_error <= rule_.rel_error) return true;
  return false;
}

std::optional<double> JobRunner::tail_alpha() const {
  return state_.tail.hill_alpha(state_.channels.empty() ? 0 : state_.channels[0].n);
}

bool JobRunner::heavy_tail() const {
  const auto a = tail_alpha();
  return a && *a < TailTracker::kWarnBelow;
}

std::optional<Prediction> JobRunner::prediction() const {
  if (!rule_.has_error_target() || state_.samples < 2) return std::nullopt;
  const Forecast f = runner_forecast(*kernel_, state_, rule_, caps_, error(), samples_per_second());
  if (!f.error_target) return std::nullopt;
  Prediction p;
  p.samples_needed = f.samples_needed;
  p.samples_remaining = std::max(0.0, f.samples_needed - static_cast<double>(state_.samples));
  const double rate = samples_per_second();
  p.seconds_remaining = rate > 0 ? p.samples_remaining / rate : kInf;
  return p;
}

double JobRunner::eta_seconds() const {
  if (finished()) return 0.0;
  const Forecast f = runner_forecast(*kernel_, state_, rule_, caps_, error(), samples_per_second());
  double eta = f.rule_seconds();
  // The error target's forecast needs σ from at least two samples.
  if (f.error_target && state_.samples < 2) {
    eta = kInf;
    if (f.max_samples) eta = std::min(eta, f.max_samples->seconds);
    if (f.time_budget) eta = std::min(eta, f.time_budget->seconds);
  }
  return eta;
}

std::vector<CostPoint> JobRunner::cost_curve(const std::vector<double>& rel_levels) const {
  std::vector<CostPoint> out;
  const ErrorSummary e = error();
  const double rate = samples_per_second();
  for (double r : rel_levels) {
    CostPoint c{r, kInf, kInf};
    if (std::isfinite(e.sigma) && e.mean != 0.0) {
      c.samples = samples_for_half_width(e.sigma, r * std::fabs(e.mean), rule_.confidence);
      c.seconds = rate > 0 ? c.samples / rate : kInf;
    }
    out.push_back(c);
  }
  return out;
}

std::vector<std::string> JobRunner::warnings() const {
  std::vector<std::string> w = kernel_->warnings(state_);
  if (const auto a = tail_alpha(); a && *a < TailTracker::kWarnBelow) {
    w.push_back(fmt::format(
        "heavy tail: estimated tail index {:.2f} (< {}); the variance may be infinite, so the "
        "standard error and interval cannot be trusted. Use importance sampling that cancels the "
        "singularity.",
        *a, TailTracker::kWarnBelow));
  }
  if (!state_.weights.empty()) {
    const double ess = state_.weights.ess();
    const double n = static_cast<double>(state_.samples);
    if (n > 0 && ess < 0.01 * n) {
      w.push_back(fmt::format("importance weights are degenerate: effective sample size {:.3g} of {}",
                              ess, state_.samples));
    }
  }
  return w;
}

}  // namespace tally
