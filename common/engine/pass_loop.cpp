#include "common/engine/pass_loop.hpp"

#include <sched.h>

#include <chrono>
#include <thread>

#include "common/engine/block_abandon.hpp"

namespace tally {

bool run_groups(const Kernel& kernel, const std::vector<Block>& blocks, const std::vector<ResultGroup>& groups,
                unsigned threads, std::vector<BlockResult>& results, const std::atomic<bool>* cancel,
                std::string_view pass_input) {
  results.clear();
  results.resize(groups.size());
  std::atomic<size_t> next{0};
  auto work = [&] {
    ScopedBlockAbandon scope(cancel);  // a cancelled pass is dropped: blocks may stop early
    BlockResult out;
    for (;;) {
      const size_t g = next.fetch_add(1, std::memory_order_relaxed);
      if (g >= groups.size()) return;
      for (size_t i = groups[g].first; i < groups[g].first + groups[g].count; ++i) {
        if (cancel != nullptr && cancel->load(std::memory_order_relaxed)) return;
        BlockResult& dst = i == groups[g].first ? results[g] : out;
        dst = BlockResult{};
        dst.block_index = blocks[i].index;
        kernel.run_block_with(blocks[i], pass_input, dst);
        if (i != groups[g].first) combine_results(results[g], out);
      }
    }
  };
  threads = std::max(1u, std::min<unsigned>(threads, static_cast<unsigned>(groups.size())));
  if (threads == 1) {
    work();
  } else {
    std::vector<std::jthread> pool;
    pool.reserve(threads - 1);
    for (unsigned t = 1; t < threads; ++t) pool.emplace_back(work);
    work();
  }
  return !(cancel != nullptr && cancel->load());
}

bool run_local(JobRunner& runner, const LocalRunOptions& options) {
  std::vector<BlockResult> results;
  while (!runner.finished() && (!options.keep_going || options.keep_going())) {
    const std::vector<Block> blocks = runner.plan_pass();
    if (blocks.empty()) break;
    const auto t0 = std::chrono::steady_clock::now();
    // One result per result group, combined as computed (run_groups).
    if (!run_groups(runner.kernel(), blocks, runner.result_groups(), options.threads, results, options.cancel,
                    runner.pass_input())) {
      runner.cancel();
      return false;
    }
    const double dt = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    runner.commit_groups(std::move(results), dt);
    results = {};
    if (options.on_pass) options.on_pass(runner);
  }
  return true;
}

unsigned available_cpus() {
  cpu_set_t set;
  CPU_ZERO(&set);
  if (sched_getaffinity(0, sizeof(set), &set) == 0) {
    const int n = CPU_COUNT(&set);
    if (n > 0) return static_cast<unsigned>(n);
  }
  const unsigned hw = std::thread::hardware_concurrency();
  return hw > 0 ? hw : 1;
}

}  // namespace tally
