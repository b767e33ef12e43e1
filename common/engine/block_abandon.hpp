#pragma once
// Lets a long block stop early once no one wants its result (the job was
// cancelled, the server is shutting down, a pilot ran out of time), so cancel and
// SIGTERM act within about a second even when one block is minutes of work (a
// 256×256 tile at 256 spp and depth 64, a sweep of 2^24 points). An executor
// points its thread at a flag around run_block (ScopedBlockAbandon); kernels poll
// block_abandoned() between pixels, paths or batches and return early; the
// executor then drops the block's result, never merges it. Thread-safe: the flag
// is an atomic the executor owns; the pointer is per thread.
#include <atomic>

namespace tally {

namespace detail {
inline thread_local const std::atomic<bool>* block_abandon_flag = nullptr;
}

// True once the block being run on this thread is no longer wanted.
inline bool block_abandoned() {
  const std::atomic<bool>* f = detail::block_abandon_flag;
  return f != nullptr && f->load(std::memory_order_relaxed);
}

class ScopedBlockAbandon {
 public:
  explicit ScopedBlockAbandon(const std::atomic<bool>* flag) : prev_(detail::block_abandon_flag) {
    detail::block_abandon_flag = flag;
  }
  ~ScopedBlockAbandon() { detail::block_abandon_flag = prev_; }
  ScopedBlockAbandon(const ScopedBlockAbandon&) = delete;
  ScopedBlockAbandon& operator=(const ScopedBlockAbandon&) = delete;

 private:
  const std::atomic<bool>* prev_;
};

}  // namespace tally
