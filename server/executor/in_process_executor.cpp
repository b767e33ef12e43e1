#include "server/executor/in_process_executor.hpp"

#include <algorithm>
#include <span>
#include <chrono>
#include <cmath>
#include <limits>

#include "common/engine/block_abandon.hpp"
#include "common/log/log.hpp"

namespace tally {

int clamp_priority(int priority) { return std::clamp(priority, -5, 5); }
double priority_weight(int priority) { return static_cast<double>(clamp_priority(priority) + 6); }

InProcessExecutor::InProcessExecutor(unsigned workers, ExecutorCallbacks callbacks, double chunk_target_seconds)
    : cb_(std::move(callbacks)), chunk_target_(chunk_target_seconds) {
  workers = std::max(1u, workers);
  threads_.reserve(workers);
  for (unsigned i = 0; i < workers; ++i) threads_.emplace_back([this] { worker_loop(); });
}

InProcessExecutor::~InProcessExecutor() { stop(); }

void InProcessExecutor::stop() {
  {
    std::lock_guard lock(mu_);
    stopping_ = true;
    for (auto& [id, a] : active_) a->abandon = true;  // blocks in flight stop early
  }
  cv_.notify_all();
  for (auto& t : threads_) {
    if (t.joinable()) t.join();
  }
  std::lock_guard lock(mu_);
  active_.clear();
  owners_.clear();
}

void InProcessExecutor::erase_locked(std::map<std::string, std::unique_ptr<Active>>::iterator it) {
  auto o = owners_.find(it->second->owner);
  if (o != owners_.end() && --o->second.jobs == 0) owners_.erase(o);
  active_.erase(it);
}

ExecutorStats InProcessExecutor::stats() const {
  ExecutorStats s;
  s.workers = workers();
  s.busy_workers = busy_workers();
  s.samples_done = samples_done();
  s.groups_streamed = groups_streamed_.load(std::memory_order_relaxed);
  s.scheduled_jobs = scheduled_jobs();
  std::lock_guard lock(mu_);
  s.cpu_seconds_by_owner = cpu_seconds_by_owner_;
  return s;
}

size_t InProcessExecutor::scheduled_jobs() const {
  std::lock_guard lock(mu_);
  return active_.size();
}

double InProcessExecutor::min_vtime_locked(const std::string& owner) const {
  double v = std::numeric_limits<double>::infinity();
  for (const auto& [id, a] : active_) {
    if (a->owner == owner) v = std::min(v, a->vtime);
  }
  return std::isfinite(v) ? v : 0.0;
}

double InProcessExecutor::min_owner_vtime_locked() const {
  double v = std::numeric_limits<double>::infinity();
  for (const auto& [name, o] : owners_) v = std::min(v, o.vtime);
  return std::isfinite(v) ? v : 0.0;
}

void InProcessExecutor::start_pass_locked(Active& a, PassWork pass) {
  a.pass = std::move(pass);
  a.results.clear();
  a.results.resize(a.pass.blocks.size());
  a.folded.assign(a.pass.blocks.size(), 0);
  a.computed.assign(a.stream ? a.pass.groups.size() : 0, 0);
  a.delivered = a.next_group = 0;
  a.broken = false;
  a.next = a.done = 0;
  a.pass_started = false;
}

void InProcessExecutor::add(ExecutorJob job, PassWork first_pass) {
  if (first_pass.empty()) return;
  {
    std::lock_guard lock(mu_);
    if (stopping_) return;
    // The job's previous run may still be here, its last pass being committed on a
    // worker (pass_done has finished the job, and an extend re-added it at once): that
    // run is over, it leaves now; the committing worker sees it was replaced.
    if (auto old = active_.find(job.id); old != active_.end()) erase_locked(old);
    auto a = std::make_unique<Active>();
    a->run = ++runs_;
    a->id = job.id;
    a->owner = job.owner;
    a->kernel = std::move(job.kernel);
    a->weight = priority_weight(job.priority);
    a->stream = job.stream_groups && static_cast<bool>(cb_.group_done);
    // Join at the current virtual times (the owner's among owners, the job's among the
    // owner's jobs): a newcomer neither starves nor is starved.
    if (!owners_.count(a->owner)) owners_[a->owner].vtime = min_owner_vtime_locked();
    owners_[a->owner].jobs += 1;
    a->vtime = min_vtime_locked(a->owner);
    start_pass_locked(*a, std::move(first_pass));
    active_[job.id] = std::move(a);
  }
  cv_.notify_all();
}

bool InProcessExecutor::cancel(const std::string& id) {
  bool call_now = false;
  {
    std::lock_guard lock(mu_);
    auto it = active_.find(id);
    if (it == active_.end()) return false;
    Active& a = *it->second;
    if (a.cancel_requested) return true;
    a.cancel_requested = true;
    a.abandon = true;  // blocks in flight stop early
    if (a.inflight == 0 && !a.committing && !a.delivering) {
      erase_locked(it);
      call_now = true;
    }
  }
  if (call_now && cb_.cancelled) cb_.cancelled(id);
  return true;
}

void InProcessExecutor::set_priority(const std::string& id, int priority) {
  std::lock_guard lock(mu_);
  if (auto it = active_.find(id); it != active_.end()) it->second->weight = priority_weight(priority);
}

double InProcessExecutor::weight_of(const std::string& id) const {
  std::lock_guard lock(mu_);
  const auto it = active_.find(id);
  return it == active_.end() ? 0.0 : it->second->weight;
}

InProcessExecutor::Active* InProcessExecutor::pick_locked() {
  Active* best = nullptr;
  double best_owner = 0.0;
  for (auto& [id, a] : active_) {
    if (a->cancel_requested || a->committing || a->next >= a->pass.blocks.size()) continue;
    if (a->stream && a->next_group >= a->delivered + stream_window()) continue;  // far enough ahead
    const double ov = owners_[a->owner].vtime;
    if (!best || ov < best_owner || (ov == best_owner && a->vtime < best->vtime)) {
      best = a.get();
      best_owner = ov;
    }
  }
  return best;
}

size_t InProcessExecutor::chunk_size_locked(const Active& a) const {
  const size_t left = a.pass.blocks.size() - a.next;
  // Spread a pass over the workers even when its blocks are cheap.
  const size_t spread = std::max<size_t>(1, (a.pass.blocks.size() + 2 * threads_.size() - 1) / (2 * threads_.size()));
  size_t n = 1;
  if (a.block_seconds > 0) {
    n = static_cast<size_t>(std::clamp(chunk_target_ / a.block_seconds, 1.0, 4096.0));
  }
  // Streamed: a chunk's results are held until it ends; keep it within the window.
  if (a.stream) n = std::min(n, stream_window());
  return std::max<size_t>(1, std::min({n, spread, left}));
}

void InProcessExecutor::worker_loop() {
  std::unique_lock lock(mu_);
  for (;;) {
    Active* a = nullptr;
    cv_.wait(lock, [&] { return stopping_ || (a = pick_locked()) != nullptr; });
    if (stopping_) return;
    const size_t begin = a->next;
    size_t end = begin + chunk_size_locked(*a);
    // Whole result groups (at most group_blocks blocks more): their blocks fold into
    // the group's first as they are computed.
    if (const auto& gs = a->pass.groups; !gs.empty()) {
      const auto it = std::upper_bound(gs.begin(), gs.end(), end - 1,
                                       [](size_t b, const ResultGroup& r) { return b < r.first; });
      if (it != gs.begin()) end = std::max(end, std::prev(it)->first + std::prev(it)->count);
      end = std::min(end, a->pass.blocks.size());
    }
    a->next = end;
    if (const auto& gs = a->pass.groups; a->stream) {
      a->next_group = static_cast<size_t>(
          std::lower_bound(gs.begin(), gs.end(), end, [](const ResultGroup& r, size_t b) { return r.first < b; }) -
          gs.begin());
    }
    a->inflight += 1;
    if (!a->pass_started) {
      a->pass_started = true;
      a->pass_start = std::chrono::steady_clock::now();
    }
    const double estimate = a->block_seconds * static_cast<double>(end - begin);
    a->vtime += estimate / a->weight;
    owners_[a->owner].vtime += estimate;
    const Kernel* kernel = a->kernel.get();
    const Block* blocks = a->pass.blocks.data();
    const std::string_view pass_input = a->pass.pass_input;
    BlockResult* results = a->results.data();
    uint8_t* folded = a->folded.data();
    const std::span<const ResultGroup> groups(a->pass.groups);
    const std::atomic<bool>* abandon = &a->abandon;  // `a` lives while inflight > 0
    lock.unlock();

    busy_.fetch_add(1, std::memory_order_relaxed);
    const auto t0 = std::chrono::steady_clock::now();
    uint64_t samples = 0;
    {
      ScopedBlockAbandon scope(abandon);
      // The group of block `begin` (groups are consecutive slots, in order).
      size_t g = static_cast<size_t>(std::upper_bound(groups.begin(), groups.end(), begin,
                                                      [](size_t b, const ResultGroup& r) { return b < r.first; }) -
                                     groups.begin());
      for (size_t i = begin; i < end && !abandon->load(std::memory_order_relaxed); ++i) {
        results[i].block_index = blocks[i].index;
        kernel->run_block_with(blocks[i], pass_input, results[i]);
        samples += blocks[i].sample_count;
        while (g < groups.size() && groups[g].first <= i) ++g;  // g - 1: block i's group
        if (g == 0) continue;
        const ResultGroup& grp = groups[g - 1];
        // Its group's earlier blocks all ran here, in order: fold it into the first
        // now (combine_groups' order, so the same bits) and free it.
        if (i > grp.first && grp.first >= begin && results[i].aux.empty() && results[grp.first].aux.empty() &&
            results[i].first_channel == results[grp.first].first_channel &&
            results[i].tallies.size() == results[grp.first].tallies.size() &&
            results[i].first_sum == results[grp.first].first_sum &&
            results[i].sums.size() == results[grp.first].sums.size()) {
          combine_results(results[grp.first], results[i]);
          results[i] = BlockResult{};
          folded[i] = 1;
        }
      }
    }
    const double dt = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    busy_.fetch_sub(1, std::memory_order_relaxed);
    samples_done_.fetch_add(samples, std::memory_order_relaxed);

    lock.lock();
    a->inflight -= 1;
    a->done += end - begin;
    a->vtime += (dt - estimate) / a->weight;
    owners_[a->owner].vtime += dt - estimate;
    cpu_seconds_by_owner_[a->owner] += dt;
    const double per_block = dt / static_cast<double>(end - begin);
    a->block_seconds = a->block_seconds > 0 ? 0.7 * a->block_seconds + 0.3 * per_block : per_block;

    if (a->stream && !a->cancel_requested && !a->abandon.load()) {
      // The chunk's groups are whole (it began and ended where groups do): computed.
      const auto& gs = a->pass.groups;
      for (size_t g = static_cast<size_t>(std::lower_bound(gs.begin(), gs.end(), begin,
                                                           [](const ResultGroup& r, size_t b) { return r.first < b; }) -
                                          gs.begin());
           g < gs.size() && gs[g].first < end; ++g) {
        a->computed[g] = 1;
      }
      deliver_locked(lock, *a);
    }
    if (a->cancel_requested) {
      if (a->inflight == 0 && !a->delivering) {
        const std::string id = a->id;
        erase_locked(active_.find(id));
        lock.unlock();
        if (cb_.cancelled) cb_.cancelled(id);
        lock.lock();
      }
      continue;
    }
    // Stopping: the results may be cut short; never commit them.
    if (a->abandon.load() || a->done < a->pass.blocks.size()) continue;
    // Streamed: the last group handed back commits the pass (this worker, or the one
    // handing groups back now, once it is done).
    if (a->stream && (a->delivering || (a->delivered < a->pass.groups.size() && !a->broken))) continue;

    // Last chunk of the pass: commit it (without the lock: other jobs keep running).
    a->committing = true;
    const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - a->pass_start).count();
    PassWork pass_done = std::move(a->pass);
    std::vector<BlockResult> results_done = std::move(a->results);
    const std::vector<uint8_t> folded_done = std::move(a->folded);
    const std::string id = a->id;
    const uint64_t run = a->run;
    const bool streamed = a->stream;
    lock.unlock();
    const auto t_merge = std::chrono::steady_clock::now();
    const uint64_t pass_no = pass_done.pass;
    const size_t pass_blocks = pass_done.blocks.size();
    std::vector<BlockResult> grouped;  // streamed: empty, its groups were handed back
    try {
      if (!streamed) grouped = combine_groups(std::move(results_done), pass_done.groups, folded_done);
    } catch (const std::exception& e) {
      // A kernel bug (results that do not combine): pass_done's commit then refuses the
      // empty pass and fails the job with an internal error, the server stays up.
      log::job(log::Level::error, id, "combining pass {}'s results failed: {}", pass_done.pass, e.what());
    }
    PassWork next = cb_.pass_done(id, pass_done, std::move(grouped), wall);
    // The in-process side of a pass boundary, to compare with the cluster's (debug level).
    log::job(log::Level::debug, id, "pass {} ({} blocks): merge {:.3f} ms", pass_no, pass_blocks,
             std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t_merge).count());
    lock.lock();
    auto it = active_.find(id);
    // Gone: stop() cleared it. Another run: the job was re-added (extend) while this,
    // its last pass, was being committed; the new run is not this worker's to end.
    if (it == active_.end() || it->second->run != run) continue;
    Active& job = *it->second;
    job.committing = false;
    if (job.cancel_requested && !next.empty()) {
      erase_locked(it);
      lock.unlock();
      if (cb_.cancelled) cb_.cancelled(id);
      lock.lock();
      continue;
    }
    if (next.empty()) {
      erase_locked(it);
      continue;
    }
    start_pass_locked(job, std::move(next));
    cv_.notify_all();
  }
}

void InProcessExecutor::deliver_locked(std::unique_lock<std::mutex>& lock, Active& a) {
  if (a.delivering) return;  // another worker hands them back; it sees these too
  a.delivering = true;
  const auto& gs = a.pass.groups;
  while (!stopping_ && !a.cancel_requested && !a.abandon.load() && !a.broken && a.delivered < gs.size() &&
         a.computed[a.delivered]) {
    const size_t g = a.delivered;
    // Blocks a worker could not fold as it computed them are combined here, in block
    // order (combine_groups' order, so the same bits).
    BlockResult r = std::move(a.results[gs[g].first]);
    bool ok = true;
    try {
      for (size_t i = gs[g].first + 1; i < gs[g].first + gs[g].count; ++i) {
        if (!a.folded[i]) combine_results(r, a.results[i]);
        a.results[i] = BlockResult{};
      }
    } catch (const std::exception& e) {
      log::job(log::Level::error, a.id, "combining result group {} of pass {} failed: {}", g, a.pass.pass, e.what());
      ok = false;
    }
    if (!ok) {
      a.broken = true;
      break;
    }
    const std::string id = a.id;
    const PassWork* pass = &a.pass;  // stays put: the pass is not replaced before it is committed
    lock.unlock();
    cb_.group_done(id, *pass, g, std::move(r));
    groups_streamed_.fetch_add(1, std::memory_order_relaxed);
    lock.lock();
    a.delivered += 1;
    cv_.notify_all();  // the window moved on
  }
  a.delivering = false;
}

}  // namespace tally
