#include "common/engine/pass_loop.hpp"

#include <sched.h>

#include <chrono>
#include <condition_variable>
#include <map>
#include <mutex>
#include <thread>

#include "common/engine/block_abandon.hpp"

namespace tally {

bool run_pass(JobRunner& runner, const std::vector<Block>& blocks, unsigned threads,
              const std::atomic<bool>* cancel) {
  const Kernel& kernel = runner.kernel();
  const std::vector<ResultGroup>& groups = runner.result_groups();
  const std::string_view pass_input = runner.pass_input();
  const auto cancelled = [&] { return cancel != nullptr && cancel->load(std::memory_order_relaxed); };
  threads = std::max(1u, std::min<unsigned>(threads, static_cast<unsigned>(std::max<size_t>(1, groups.size()))));
  const size_t window = 4 * static_cast<size_t>(threads);
  std::mutex mu;
  std::condition_variable cv;
  size_t next = 0;                      // the next group to hand out
  size_t merged = 0;                    // groups merged into the runner
  bool stop = false;                    // cancelled: hand out and merge nothing more
  std::map<size_t, BlockResult> ready;  // finished groups waiting for those before them
  auto work = [&] {
    ScopedBlockAbandon scope(cancel);  // a cancelled pass is dropped: blocks may stop early
    BlockResult out;
    for (;;) {
      size_t g = 0;
      {
        std::unique_lock lock(mu);
        cv.wait(lock, [&] { return stop || next >= groups.size() || next < merged + window; });
        if (stop || next >= groups.size()) return;
        g = next++;
      }
      BlockResult acc;
      for (size_t i = groups[g].first; i < groups[g].first + groups[g].count && !cancelled(); ++i) {
        BlockResult& dst = i == groups[g].first ? acc : out;
        dst = BlockResult{};
        dst.block_index = blocks[i].index;
        kernel.run_block_with(blocks[i], pass_input, dst);
        if (i != groups[g].first) combine_results(acc, out);
      }
      std::lock_guard lock(mu);
      if (stop || cancelled()) {  // the group may be cut short: never merge it
        stop = true;
        cv.notify_all();
        return;
      }
      ready.emplace(g, std::move(acc));
      while (!ready.empty() && ready.begin()->first == merged) {
        runner.merge_group(std::move(ready.begin()->second));
        ready.erase(ready.begin());
        ++merged;
      }
      cv.notify_all();
    }
  };
  if (threads == 1) {
    work();
  } else {
    std::vector<std::jthread> pool;
    pool.reserve(threads - 1);
    for (unsigned t = 1; t < threads; ++t) pool.emplace_back(work);
    work();
  }
  return !stop && merged == groups.size();
}

bool run_local(JobRunner& runner, const LocalRunOptions& options) {
  while (!runner.finished() && (!options.keep_going || options.keep_going())) {
    const std::vector<Block> blocks = runner.plan_pass();
    if (blocks.empty()) break;
    const auto t0 = std::chrono::steady_clock::now();
    if (!run_pass(runner, blocks, options.threads, options.cancel)) {
      runner.cancel();
      return false;
    }
    runner.finish_pass(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
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
