// tally-test-worker: tally-worker with a fault-injecting kernel wrapper, for the cluster
// tests only (never installed). TALLY_TEST_FAULT holds comma-separated directives about
// blocks, matched by the block's first sample (unique within a job run):
//   sleep_ms=N        every block sleeps N ms before computing (long blocks, no CPU)
//   sleep_at=S:N      the block starting at sample S sleeps N ms
//   throw_at=S        the block starting at sample S throws (a kernel error)
//   abort_at=S        the block starting at sample S aborts the process (a crash)
// Each fault prints one line to stderr ("test fault: ..."), so a test counts deliveries
// in the worker's log. Results are otherwise the wrapped kernel's, bit for bit.
#include <fmt/format.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <span>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>

#include "server/cluster/worker.hpp"

namespace {

using tally::Block;
using tally::BlockResult;
using tally::Kernel;

struct Faults {
  long sleep_ms = 0;
  long long sleep_at = -1;
  long sleep_at_ms = 0;
  long long throw_at = -1;
  long long abort_at = -1;
};

Faults parse_faults(const char* env) {
  Faults f;
  if (!env) return f;
  std::stringstream ss(env);
  std::string item;
  while (std::getline(ss, item, ',')) {
    const auto eq = item.find('=');
    if (eq == std::string::npos) continue;
    const std::string key = item.substr(0, eq), value = item.substr(eq + 1);
    if (key == "sleep_ms") f.sleep_ms = std::stol(value);
    if (key == "sleep_at") {
      const auto colon = value.find(':');
      f.sleep_at = std::stoll(value.substr(0, colon));
      f.sleep_at_ms = std::stol(value.substr(colon + 1));
    }
    if (key == "throw_at") f.throw_at = std::stoll(value);
    if (key == "abort_at") f.abort_at = std::stoll(value);
  }
  return f;
}

class FaultKernel final : public Kernel {
 public:
  FaultKernel(std::shared_ptr<const Kernel> inner, Faults f) : inner_(std::move(inner)), f_(f) {}
  size_t channel_count() const override { return inner_->channel_count(); }
  uint32_t partition_count() const override { return inner_->partition_count(); }
  tally::PassSchedule schedule() const override { return inner_->schedule(); }
  std::vector<uint32_t> active_partitions(const tally::JobState& s) const override { return inner_->active_partitions(s); }
  void run_block(const Block& block, BlockResult& out) const override { run_block_with(block, {}, out); }
  std::string pass_input(const tally::JobState& s) const override { return inner_->pass_input(s); }
  void run_block_with(const Block& block, std::string_view input, BlockResult& out) const override {
    const auto first = static_cast<long long>(block.first_sample);
    if (first == f_.abort_at) {
      fmt::print(stderr, "test fault: block at sample {} aborts the worker\n", first);
      std::fflush(stderr);
      std::abort();
    }
    if (first == f_.throw_at) {
      fmt::print(stderr, "test fault: block at sample {} throws\n", first);
      throw std::runtime_error(fmt::format("test fault: the kernel threw on the block at sample {}", first));
    }
    long ms = f_.sleep_ms;
    if (first == f_.sleep_at) {
      ms = f_.sleep_at_ms;
      fmt::print(stderr, "test fault: block at sample {} sleeps {} ms\n", first, ms);
    }
    if (ms > 0) std::this_thread::sleep_for(std::chrono::milliseconds(ms));
    inner_->run_block_with(block, input, out);
  }
  void fold_pass(std::string_view input, const std::vector<BlockResult>& r, tally::JobState& s) const override {
    inner_->fold_pass(input, r, s);
  }
  bool folds_passes() const override { return inner_->folds_passes(); }
  std::span<const std::string_view> counter_names() const override { return inner_->counter_names(); }
  std::vector<std::string> warnings(const tally::JobState& s) const override { return inner_->warnings(s); }
  tally::ErrorSummary error_summary(const tally::JobState& s, double c) const override {
    return inner_->error_summary(s, c);
  }
  std::optional<tally::Headline> headline(const tally::JobState& s) const override { return inner_->headline(s); }

 private:
  std::shared_ptr<const Kernel> inner_;
  Faults f_;
};

}  // namespace

int main(int argc, char** argv) {
  const Faults f = parse_faults(std::getenv("TALLY_TEST_FAULT"));
  return tally::cluster::worker_main(argc, argv, [f](std::shared_ptr<const Kernel> k) -> std::shared_ptr<const Kernel> {
    return std::make_shared<FaultKernel>(std::move(k), f);
  });
}
