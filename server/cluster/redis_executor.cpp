#include "server/cluster/redis_executor.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <set>

#include "common/log/log.hpp"
#include "common/spec/pool_field.hpp"
#include "server/cluster/cluster_store.hpp"
#include "server/cluster/pass_verdict.hpp"
#include "server/cluster/result_key.hpp"

namespace tally::cluster {

namespace {

// Passes whose results came to at least this many bytes are read while they run.
constexpr size_t kPrefetchBytes = 256 * 1024;

using Clock = std::chrono::steady_clock;

double unix_seconds() {
  return std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
}

// Milliseconds since `t`, for the pass-boundary latency lines (debug level).
double ms_since(Clock::time_point t) { return std::chrono::duration<double, std::milli>(Clock::now() - t).count(); }

}  // namespace

RedisExecutor::RedisExecutor(RedisExecutorConfig config, ExecutorCallbacks callbacks)
    : cfg_(std::move(config)),
      cb_(std::move(callbacks)),
      monitor_(cfg_.lease, cfg_.url.display()),
      waker_(cfg_.url) {
  not_ready_ = fmt::format("connecting to redis at {}", cfg_.url.display());
  thread_ = std::thread([this] { loop(); });
}

RedisExecutor::~RedisExecutor() { stop(); }

void RedisExecutor::stop() {
  {
    std::lock_guard lock(mu_);
    stopping_ = true;
  }
  cv_.notify_all();
  waker_.stop();
  if (thread_.joinable()) thread_.join();
  std::lock_guard lock(mu_);
  jobs_.clear();
}

void RedisExecutor::add(ExecutorJob ej, PassWork first_pass) {
  if (first_pass.empty()) return;
  auto job = std::make_unique<Job>();
  // The assets are read here, on the caller's thread (not an I/O thread: the manager
  // starts jobs from its own paths); a job whose files vanished fails at once.
  std::string asset_error;
  try {
    const nlohmann::json spec = nlohmann::json::parse(ej.spec_json);
    job->assets = collect_assets(spec, cfg_.asset_dir, cfg_.asset_store);
    job->manifest = asset_manifest(job->assets).dump();
    job->pool = spec_pool(spec);
  } catch (const std::exception& e) {
    asset_error = fmt::format("cannot publish the job's assets: {}", e.what());
  }
  const std::string id = ej.id;
  if (!asset_error.empty()) {
    log::job(log::Level::error, id, "{}", asset_error);
    if (cb_.failed) cb_.failed(id, asset_error);
    return;
  }
  job->ej = std::move(ej);
  if (first_pass.ahead) {
    job->ahead = std::make_unique<PassRun>();
    job->ahead->work = *first_pass.ahead;
  }
  first_pass.ahead.reset();
  job->cur.work = std::move(first_pass);
  job->active = active_key(job->pool);
  {
    std::lock_guard lock(mu_);
    if (stopping_) return;
    job->run = fmt::format("{}.{}", job->ej.epoch, ++generation_);
    job->blocks.pending = job->cur.work.blocks.size();
    jobs_[id] = std::move(job);
  }
  cv_.notify_all();
  waker_.wake();
}

RedisExecutor::Job* RedisExecutor::find(const std::string& id) const {
  std::lock_guard lock(mu_);
  auto it = jobs_.find(id);
  return it == jobs_.end() ? nullptr : it->second.get();
}

bool RedisExecutor::cancel(const std::string& id) {
  {
    std::lock_guard lock(mu_);
    auto it = jobs_.find(id);
    if (it == jobs_.end()) return false;
    it->second->cancel_requested = true;
  }
  cv_.notify_all();
  waker_.wake();
  return true;
}

ExecutorStats RedisExecutor::stats() const {
  ExecutorStats s;
  monitor_.count_live(s.workers, s.busy_workers);
  std::lock_guard lock(mu_);
  s.samples_done = samples_done_;
  s.groups_streamed = groups_streamed_;
  s.scheduled_jobs = jobs_.size();
  for (const auto& [id, j] : jobs_) s.blocks_by_job[id] = j->blocks;
  return s;
}

bool RedisExecutor::redis_reachable() const {
  std::lock_guard lock(mu_);
  return !not_ready_.has_value();
}

std::optional<std::string> RedisExecutor::not_ready_reason() const {
  {
    std::lock_guard lock(mu_);
    if (not_ready_) return not_ready_;
  }
  return monitor_.redis_problem();
}

std::optional<std::string> RedisExecutor::waiting_reason(const std::string& id) const {
  const std::optional<std::string> pool = pool_of(id);
  if (!pool) return std::nullopt;
  if (auto why = not_ready_reason()) return fmt::format("paused: {}; the job resumes when Redis can take it", *why);
  return monitor_.waiting_for_workers(*pool);
}

std::set<std::string> RedisExecutor::job_pools() const {
  std::lock_guard lock(mu_);
  std::set<std::string> pools;
  for (const auto& [id, j] : jobs_) {
    if (!j->pool.empty()) pools.insert(j->pool);
  }
  return pools;
}

bool RedisExecutor::holds_queued(const std::string& id) const {
  const std::optional<std::string> pool = pool_of(id);
  return pool && !pool->empty() && !monitor_.any_live(*pool);
}

std::optional<std::string> RedisExecutor::pool_of(const std::string& id) const {
  std::lock_guard lock(mu_);
  auto it = jobs_.find(id);
  if (it == jobs_.end()) return std::nullopt;
  return it->second->pool;
}

// ---------------------------------------------------------------- coordinator thread

bool RedisExecutor::connect() {
  try {
    conn_ = std::make_unique<RedisConn>(cfg_.url, std::chrono::milliseconds(5000));
    const std::string rid = conn_->run_id();
    announce_lease(*conn_, cfg_.lease);
    if (first_connect_) {
      // This process is the only coordinator: stream keys in the active sets belong to
      // an earlier run of it and are swept job by job as the jobs come back.
      clear_active_sets(*conn_);
    }
    const bool restarted = !first_connect_ && rid != run_id_;
    first_connect_ = false;
    run_id_ = rid;
    std::lock_guard lock(mu_);
    for (auto& [id, j] : jobs_) {
      // After a Redis restart everything unmerged is gone: publish it again. After a
      // mere disconnect, publishing again is harmless too (results already stored stay).
      j->cur.published = false;
      if (j->ahead) j->ahead->published = false;
      if (restarted) j->swept = j->hash_written = false;
    }
    if (restarted) {
      monitor_.count_republished(jobs_.size());
      log::warn("redis restarted (run_id changed): republishing {} job(s)", jobs_.size());
    }
    if (not_ready_) log::info("redis at {} is reachable", cfg_.url.display());
    not_ready_.reset();
    return true;
  } catch (const RedisIoError& e) {
    conn_.reset();
    std::lock_guard lock(mu_);
    const std::string reason = fmt::format("redis unreachable at {}: {}", cfg_.url.display(), e.what());
    if (!not_ready_ || *not_ready_ != reason) log::warn("{}; jobs are paused", reason);
    not_ready_ = reason;
    return false;
  }
}

void RedisExecutor::loop() {
  for (;;) {
    {
      std::lock_guard lock(mu_);
      if (stopping_) return;
    }
    if (!conn_ && !connect()) {
      std::unique_lock lock(mu_);
      cv_.wait_for(lock, std::chrono::milliseconds(500), [&] { return stopping_; });
      continue;
    }
    try {
      step();
    } catch (const RedisIoError& e) {
      conn_.reset();
      std::lock_guard lock(mu_);
      not_ready_ = fmt::format("redis unreachable at {}: {}", cfg_.url.display(), e.what());
      log::warn("{}; jobs are paused", *not_ready_);
    } catch (const std::exception& e) {
      // A reply we did not expect (e.g. a key of the wrong type), or Redis out of
      // memory (said once per episode: /readyz and the jobs' status say it meanwhile):
      // log, retry later.
      const bool was_full = monitor_.redis_problem().has_value();
      if (!monitor_.note_redis_error(e.what()) || !was_full) log::error("cluster coordinator: {}", e.what());
      std::unique_lock lock(mu_);
      cv_.wait_for(lock, std::chrono::milliseconds(200), [&] { return stopping_; });
    }
  }
}

void RedisExecutor::step() {
  clean_finished();
  // Cancels first: their keys go, so no worker starts another of their blocks.
  std::vector<std::string> to_cancel, to_publish;
  // A pass with large results is out: they are read as they arrive (every 10 ms), so
  // the boundary reads only the last ones. Small results (an integral's pass: tens of
  // KB) are read at the end; waking every 10 ms for them cost Redis and the
  // coordinator ~5 % of a core each.
  bool running = false;
  {
    std::lock_guard lock(mu_);
    for (auto& [id, j] : jobs_) {
      if (j->cancel_requested) {
        to_cancel.push_back(id);
      } else if (!j->all_published()) {
        to_publish.push_back(id);
      } else if (j->last_pass_bytes >= kPrefetchBytes) {
        running = true;
      }
    }
  }
  for (const auto& id : to_cancel) leave(id, false, {});
  for (const auto& id : to_publish) {
    Job* j = find(id);
    if (!j) continue;
    publish(*j);
  }

  // Wait briefly for a completed pass (the store script pushes the job id); while passes
  // with large results run, wake every 10 ms to read the entries stored meanwhile.
  // Woken by the waker (add, cancel) or a pass.
  const Notified notified = wait_notified(*conn_, running || !to_publish.empty() ? "0.01" : "0.05");
  notified_at_ = Clock::now();
  const auto now = Clock::now();
  if (now - last_poll_ >= std::chrono::milliseconds(250)) {
    last_poll_ = now;
    poll({});  // also catches lost notifications and streams Redis lost
  } else if (!notified.jobs.empty()) {
    poll(notified.jobs);
  }
  if (!notified.woken) prefetch();
  if (now - last_refresh_ >= std::chrono::milliseconds(500)) {
    last_refresh_ = now;
    refresh();
  }
}

void RedisExecutor::publish(Job& job) {
  if (!job.swept) {
    // Keys of this job from an earlier run (older epoch, a coordinator that died, a
    // cancelled run before an extend): deleted so they are never read or merged.
    sweep_other_runs(*conn_, job.ej.id, job.run, job.active);
    job.swept = true;
  }
  if (!job.hash_written) {
    // Once per run (and again if Redis lost it), not at every pass or reconnect: a
    // "failed" or "mismatch" mark a worker set while the connection was down must
    // survive a reconnect, and the spec and assets need not travel again.
    const std::string& key = cfg_.result_key;
    const std::string mac = key.empty() ? std::string() : spec_mac(key, job.ej.id, job.run, job.ej.spec_json, job.manifest);
    write_job(*conn_, {job.ej.id, job.run, job.ej.spec_json, job.manifest, mac, cfg_.max_failures}, job.assets);
    job.hash_written = true;
  }
  if (!job.cur.published) publish_pass(job, job.cur);
  if (job.ahead && !job.ahead->published) publish_pass(job, *job.ahead);
}

void RedisExecutor::publish_pass(Job& job, PassRun& pass) {
  const PassKeys keys(job.ej.id, job.run, pass.work.pass);
  const size_t n = pass.work.blocks.size();
  // Entries already stored (a republish after a reconnect without a Redis restart) need
  // no new stream entry. A pass published for the first time has none: skip the round trip.
  std::set<size_t> have;  // first slots
  if (pass.was_published) {
    for (const std::string& k : stored_entry_slots(*conn_, keys)) have.insert(std::stoull(k));
  }
  if (pass.plan.entries.empty()) {
    EntryPlan plan = plan_entries(pass.work, monitor_.live_threads(), job.block_seconds, cfg_.max_entry_blocks, job.ej.id);
    std::lock_guard lock(mu_);
    pass.plan = std::move(plan);
  }
  size_t stored_blocks = 0;
  const PassPublication pub = publication(pass.work, pass.plan, have, stored_blocks);
  // The whole pass in one round trip (workers without work wait until this lands).
  cluster::publish_pass(*conn_, keys, job.active, job.ej.id, pub);
  std::lock_guard lock(mu_);
  if (pass.start == Clock::time_point{}) pass.start = Clock::now();
  pass.published = true;
  pass.was_published = true;
  if (&pass == &job.cur) job.blocks.pending = n - std::min(n, stored_blocks);
}

void RedisExecutor::poll(const std::vector<std::string>& ids) {
  struct Probe {
    std::string id;
    PassKeys keys;
    size_t entries;  // result fields of a complete pass
  };
  std::vector<Probe> probes;
  {
    std::lock_guard lock(mu_);
    auto add_probe = [&](const Job& j) {
      if (!j.cur.published || j.cancel_requested) return;
      probes.push_back({j.ej.id, PassKeys(j.ej.id, j.run, j.cur.work.pass), j.cur.plan.entries.size()});
    };
    if (ids.empty()) {
      for (const auto& [id, j] : jobs_) add_probe(*j);
    } else {
      for (const auto& id : ids) {
        if (auto it = jobs_.find(id); it != jobs_.end()) add_probe(*it->second);
      }
    }
  }
  std::vector<PassProbe> asked;
  for (const Probe& pr : probes) asked.push_back({&pr.keys, job_key(pr.id)});
  const std::vector<PassState> states = probe_passes(*conn_, asked);
  for (size_t i = 0; i < probes.size(); ++i) {
    const std::string& id = probes[i].id;
    const PassVerdict v = judge_pass(states[i], probes[i].entries);
    switch (v.what) {
      case PassVerdict::merge: merge(id); break;
      case PassVerdict::fail:
        log::job(log::Level::error, id, "{}", v.error);
        leave(id, true, v.error);
        break;
      case PassVerdict::republish: {
        std::lock_guard lock(mu_);
        if (auto it = jobs_.find(id); it != jobs_.end()) {
          it->second->cur.published = false;
          if (it->second->ahead) it->second->ahead->published = false;
          it->second->hash_written = false;  // the job hash may be gone too
          monitor_.count_republished(1);
          log::job(log::Level::warn, id, "its pass vanished from Redis; republishing");
        }
        break;
      }
      case PassVerdict::nothing: break;
    }
  }
}

void RedisExecutor::prefetch() {
  // Results are read and decoded while the passes run (one HKEYS per pass, then only the
  // entries not read yet), so the pass boundary, where the current pass is merged,
  // reads only the last entries.
  std::vector<std::string> ids;
  {
    std::lock_guard lock(mu_);
    for (const auto& [id, j] : jobs_) {
      if (j->cur.published && !j->cancel_requested) ids.push_back(id);
    }
  }
  for (const auto& id : ids) {
    Job* job = find(id);
    if (!job) continue;
    size_t bytes = 0;
    std::string error = job->read_results(*conn_, job->cur, true, bytes, cfg_.result_key);
    if (error.empty()) deliver(*job);
    if (error.empty() && job->ahead && job->ahead->published) {
      error = job->read_results(*conn_, *job->ahead, true, bytes, cfg_.result_key);
    }
    if (!error.empty()) {
      log::job(log::Level::error, id, "{}", error);
      leave(id, true, error);
    }
  }
}

void RedisExecutor::deliver(Job& job) {
  if (!streams(job)) return;
  {
    std::lock_guard lock(mu_);
    if (job.cancel_requested) return;
  }
  // Its merges wait for a checkpoint: not on this thread, which serves every job; the
  // next prefetch or poll hands them back (a complete pass is polled every 250 ms).
  if (cb_.merges_held && cb_.merges_held(job.ej.id)) return;
  ClusterPassRun& run = job.cur;
  while (run.delivered < run.got.size() && run.got[run.delivered]) {
    BlockResult r = std::move(*run.got[run.delivered]);
    run.got[run.delivered].reset();
    const size_t g = run.delivered++;
    cb_.group_done(job.ej.id, run.work, g, std::move(r));
    std::lock_guard lock(mu_);
    ++groups_streamed_;
  }
}

void RedisExecutor::merge(const std::string& id) {
  Job* job;
  {
    std::lock_guard lock(mu_);
    auto it = jobs_.find(id);
    if (it == jobs_.end() || it->second->cancel_requested) return;
    job = it->second.get();
  }
  PassRun& run = job->cur;
  const PassWork& pass = run.work;
  const size_t n = pass.blocks.size();
  const size_t ng = pass.groups.size();
  const auto t_read = Clock::now();
  const size_t had = run.got.size() == ng ? run.got_count : 0;
  size_t result_bytes = 0;
  const std::string error = job->read_results(*conn_, run, false, result_bytes, cfg_.result_key);
  if (!error.empty() || run.got_count >= run.work.groups.size()) job->last_pass_bytes = run.bytes_read;
  if (!error.empty()) {
    log::job(log::Level::error, id, "{}", error);
    leave(id, true, error);
    return;
  }
  deliver(*job);
  if (run.got_count < ng) return;  // not complete yet
  // Streamed, with its merges held (a checkpoint): a later poll hands the rest back.
  if (streams(*job) && run.delivered < ng) return;
  const double read_ms = ms_since(t_read);
  const auto t_decode = Clock::now();
  // Streamed: every group went to the manager already (deliver); pass_done gets none.
  std::vector<BlockResult> results(run.delivered == ng ? 0 : ng);
  for (size_t i = 0; i < results.size(); ++i) results[i] = std::move(*run.got[i]);
  run.got.clear();
  run.got_count = 0;
  const double decode_ms = ms_since(t_decode);
  const double wall = std::chrono::duration<double>(Clock::now() - run.start).count();
  try {
    if (const double secs = measured_block_seconds(*conn_, id); secs > 0) job->block_seconds = secs;
  } catch (const std::exception& e) {
    log::job(log::Level::debug, id, "no block time measured yet ({}): entries stay one block long", e.what());
  }
  // The pass is merged: its stream, inputs and results go. Digests stay a few passes
  // so a late duplicate is still compared.
  std::vector<size_t> slots;
  for (const auto& [first, count] : run.plan.entries) slots.push_back(first);
  const std::vector<PassKeys> old_digests = job->retire_current(cfg_.digest_passes);
  for (const std::string& e : drop_merged_pass(*conn_, PassKeys(id, job->run, pass.pass), job->active, slots, old_digests)) {
    log::job(log::Level::warn, id, "deleting a merged pass's keys: {}", e);
  }
  uint64_t samples = 0;
  for (const Block& b : pass.blocks) samples += b.sample_count;
  monitor_.count_merged(n);
  {
    std::lock_guard lock(mu_);
    samples_done_ += samples;
  }
  const auto t_merge = Clock::now();
  const uint64_t pass_no = pass.pass;
  PassWork next = cb_.pass_done(id, pass, std::move(results), wall);
  const double merge_ms = ms_since(t_merge);
  if (next.empty()) {
    // The job is done: it leaves at once, whatever happens to Redis now. Its keys go
    // next (with a pass published ahead, if any); if Redis is unreachable they are
    // deleted after the reconnect, never republished (a finished job's last pass
    // computed again would be merged into a job that has ended).
    {
      std::lock_guard lock(mu_);
      auto it = jobs_.find(id);
      finished_.push_back(std::move(it->second));
      jobs_.erase(it);
    }
    clean_finished();
    return;
  }
  Job::Advance how;
  {
    std::lock_guard lock(mu_);
    const uint64_t ahead_pass = job->ahead ? job->ahead->work.pass : 0;
    how = job->advance(std::move(next), [&] { return fmt::format("{}.{}", job->ej.epoch, ++generation_); });
    if (how == Job::Advance::adopted) monitor_.count_ahead();
    if (how == Job::Advance::restarted) {
      log::job(log::Level::warn, id, "the pass published ahead ({}) differs from the pass planned; it is dropped",
               ahead_pass);
    }
  }
  const bool adopted = how == Job::Advance::adopted;
  if (job->cancel_requested) return;
  const auto t_publish = Clock::now();
  publish(*job);
  // The adopted pass may be complete already (its completion was announced while it was
  // ahead): look at it in the next step.
  if (adopted) notify_job(*conn_, id);
  // One line per pass boundary: where the coordinator's serial time goes.
  log::job(log::Level::debug, id,
           "pass {} ({} blocks, {} result groups, {} read before the end, {} result bytes read at the end): noticed "
           "{:.3f} ms after "
           "BLPOP returned, read + decode {:.3f} ms, collect {:.3f} ms, merge {:.3f} ms, publish {:.3f} ms ({} "
           "entries{}), boundary {:.3f} ms; at unix {:.6f}",
           pass_no, n, ng, had, result_bytes, std::chrono::duration<double, std::milli>(t_read - notified_at_).count(),
           read_ms, decode_ms, merge_ms, ms_since(t_publish), job->cur.plan.entries.size(),
           adopted ? ", published ahead" : "",
           std::chrono::duration<double, std::milli>(Clock::now() - notified_at_).count(), unix_seconds());
}

void RedisExecutor::clean_finished() {
  while (!finished_.empty()) {
    delete_job_keys(*finished_.front());
    finished_.pop_front();
  }
}

void RedisExecutor::delete_job_keys(Job& job) {
  delete_job(*conn_, job.ej.id, job.passes_out(), job.digest_keys(), job.active);
  job.digest_passes.clear();
}

void RedisExecutor::leave(const std::string& id, bool failed, const std::string& error) {
  Job* job = find(id);
  if (!job) return;
  delete_job_keys(*job);  // a late result finds no run: stale, never merged
  {
    std::lock_guard lock(mu_);
    jobs_.erase(id);
  }
  if (failed) {
    if (cb_.failed) cb_.failed(id, error);
  } else if (cb_.cancelled) {
    cb_.cancelled(id);
  }
}

void RedisExecutor::refresh() {
  monitor_.refresh(*conn_);
  // Per job: blocks in flight (pending entries) and redelivered.
  struct Probe {
    std::string id;
    PassKeys keys;
    uint64_t n, k;
  };
  std::vector<Probe> probes;
  {
    std::lock_guard lock(mu_);
    for (const auto& [id, j] : jobs_) {
      if (j->cur.published) {
        probes.push_back({id, PassKeys(id, j->run, j->cur.work.pass), j->cur.work.blocks.size(), j->cur.plan.entry_blocks});
      }
    }
  }
  std::vector<PassProbe> asked;
  for (const Probe& p : probes) asked.push_back({&p.keys, job_key(p.id)});
  const std::vector<PassFlight> flights = probe_flight(*conn_, asked);
  // A job whose entry was delivered again and again without a result fails, rather
  // than loop forever (crash_loop).
  std::vector<std::pair<std::string, std::string>> crashed;
  std::map<std::string, ExecutorStats::JobBlocks> flight;
  // While Redis is (or was lately) out of memory, deliveries fail for that: no crash.
  const bool oom = monitor_.out_of_memory_within(cfg_.lease * (cfg_.max_failures + 2));
  for (size_t i = 0; i < probes.size(); ++i) {
    if (auto error = crash_loop(flights[i], cfg_.max_failures); error && !oom) {
      crashed.emplace_back(probes[i].id, std::move(*error));
    }
    flight[probes[i].id] = blocks_in_flight(flights[i], probes[i].n, probes[i].k);
  }
  std::unique_lock lock(mu_);
  for (auto& [id, j] : jobs_) {
    auto it = flight.find(id);
    if (it == flight.end()) continue;
    j->blocks = it->second;
  }
  lock.unlock();
  for (const auto& [id, error] : crashed) {
    log::job(log::Level::error, id, "{}", error);
    leave(id, true, error);
  }
}

}  // namespace tally::cluster
