#include "server/cluster/redis_executor.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cstdio>
#include <set>

#include "common/engine/check.hpp"
#include "common/log/log.hpp"
#include "server/cluster/protocol.hpp"
#include "server/cluster/wire.hpp"

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

// Live workers: a heartbeat within this many leases (at least 10 s).
double worker_timeout_s(std::chrono::milliseconds lease) {
  return std::max(10.0, 3.0 * static_cast<double>(lease.count()) / 1000.0);
}

}  // namespace

RedisExecutor::RedisExecutor(RedisExecutorConfig config, ExecutorCallbacks callbacks)
    : cfg_(std::move(config)), cb_(std::move(callbacks)) {
  not_ready_ = fmt::format("connecting to redis at {}", cfg_.url.display());
  thread_ = std::thread([this] { loop(); });
  waker_ = std::thread([this] { wake_loop(); });
}

void RedisExecutor::wake() {
  {
    std::lock_guard lock(mu_);
    wake_ = true;
  }
  wake_cv_.notify_all();
}

void RedisExecutor::wake_loop() {
  std::unique_ptr<RedisConn> conn;
  for (;;) {
    {
      std::unique_lock lock(mu_);
      wake_cv_.wait(lock, [&] { return stopping_ || wake_; });
      if (stopping_) return;
      wake_ = false;
    }
    try {
      if (!conn) conn = std::make_unique<RedisConn>(cfg_.url, std::chrono::milliseconds(1000));
      conn->cmd({"RPUSH", kNotify, kWakeMarker});
    } catch (const std::exception& e) {
      // Harmless: the coordinator's wait ends by its timeout (<= 50 ms) anyway.
      conn.reset();
      log::write(log::Level::debug, "", fmt::format("cluster waker: {}", e.what()));
    }
  }
}

RedisExecutor::~RedisExecutor() { stop(); }

void RedisExecutor::stop() {
  {
    std::lock_guard lock(mu_);
    stopping_ = true;
  }
  cv_.notify_all();
  wake_cv_.notify_all();
  if (thread_.joinable()) thread_.join();
  if (waker_.joinable()) waker_.join();
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
    job->assets = collect_assets(nlohmann::json::parse(ej.spec_json), cfg_.asset_dir, cfg_.asset_store);
    job->manifest = asset_manifest(job->assets).dump();
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
  {
    std::lock_guard lock(mu_);
    if (stopping_) return;
    job->run = fmt::format("{}.{}", job->ej.epoch, ++generation_);
    job->blocks.pending = job->cur.work.blocks.size();
    jobs_[id] = std::move(job);
  }
  cv_.notify_all();
  wake();
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
  wake();
  return true;
}

ExecutorStats RedisExecutor::stats() const {
  std::lock_guard lock(mu_);
  ExecutorStats s;
  const double now = unix_seconds();
  for (const auto& w : workers_) {
    if (now - w.last_heartbeat > worker_timeout_s(cfg_.lease)) continue;
    s.workers += w.threads;
    if (!w.current_job.empty()) s.busy_workers += 1;
  }
  s.samples_done = samples_done_;
  s.scheduled_jobs = jobs_.size();
  for (const auto& [id, j] : jobs_) s.blocks_by_job[id] = j->blocks;
  return s;
}

std::optional<std::string> RedisExecutor::not_ready_reason() const {
  std::lock_guard lock(mu_);
  return not_ready_;
}

std::optional<std::string> RedisExecutor::waiting_reason(const std::string& id) const {
  std::lock_guard lock(mu_);
  if (!jobs_.count(id)) return std::nullopt;
  if (not_ready_) return fmt::format("paused: {}; the job resumes when Redis is back", *not_ready_);
  const double now = unix_seconds();
  const bool any = std::any_of(workers_.begin(), workers_.end(),
                               [&](const WorkerInfo& w) { return now - w.last_heartbeat <= worker_timeout_s(cfg_.lease); });
  if (!any) return std::string("waiting for a tally-worker: none is connected to Redis");
  return std::nullopt;
}

std::vector<WorkerInfo> RedisExecutor::workers() const {
  std::lock_guard lock(mu_);
  return workers_;
}

ClusterCounters RedisExecutor::counters() const {
  std::lock_guard lock(mu_);
  return counters_;
}

// ---------------------------------------------------------------- coordinator thread

bool RedisExecutor::connect() {
  try {
    conn_ = std::make_unique<RedisConn>(cfg_.url, std::chrono::milliseconds(5000));
    const std::string rid = conn_->run_id();
    conn_->cmd({"HSET", "tally:config", "lease_ms", std::to_string(cfg_.lease.count())});
    if (first_connect_) {
      // This process is the only coordinator: stream keys in the active set belong to
      // an earlier run of it and are swept job by job as the jobs come back.
      conn_->cmd({"DEL", kActive});
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
      counters_.republished += jobs_.size();
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
      // A reply we did not expect (e.g. a key of the wrong type): log, retry later.
      log::error("cluster coordinator: {}", e.what());
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
  std::vector<std::string> notified;
  const RValue r = conn_->cmd({"BLPOP", kNotify, running || !to_publish.empty() ? "0.01" : "0.05"});
  notified_at_ = Clock::now();
  bool woken = false;  // by the waker (add, cancel) or a pass
  if (r.is_array() && r.elems.size() == 2) {
    woken = true;
    if (r.elems[1].str != kWakeMarker) notified.push_back(r.elems[1].str);
    // The rest in one round trip (LPOP with a count: Redis 6.2, as XAUTOCLAIM).
    const RValue more = conn_->cmd({"LPOP", kNotify, "1000"});
    for (const RValue& m : more.elems) {
      if (m.str != kWakeMarker) notified.push_back(m.str);
    }
  }
  const auto now = Clock::now();
  if (now - last_poll_ >= std::chrono::milliseconds(250)) {
    last_poll_ = now;
    poll({});  // also catches lost notifications and streams Redis lost
  } else if (!notified.empty()) {
    poll(notified);
  }
  if (!woken) prefetch();
  if (now - last_refresh_ >= std::chrono::milliseconds(500)) {
    last_refresh_ = now;
    refresh();
  }
}

void RedisExecutor::sweep(const Job& job) {
  // Keys of this job from an earlier run (older epoch, a coordinator that died, a
  // cancelled run before an extend): delete them so they are never read or merged.
  const std::string pattern = fmt::format("tally:?:{}:*", job.ej.id);
  std::string cursor = "0";
  do {
    const RValue r = conn_->cmd({"SCAN", cursor, "MATCH", pattern, "COUNT", "1000"});
    if (!r.is_array() || r.elems.size() != 2) break;
    cursor = r.elems[0].str;
    for (const RValue& k : r.elems[1].elems) {
      if (k.str.find(":" + job.run + ":") != std::string::npos) continue;
      conn_->cmd({"DEL", k.str});
      conn_->cmd({"SREM", kActive, k.str});
    }
  } while (cursor != "0");
}

void RedisExecutor::publish(Job& job) {
  if (!job.swept) {
    sweep(job);
    job.swept = true;
  }
  if (!job.hash_written) {
    // Once per run (and again if Redis lost it), not at every pass or reconnect: a
    // "failed" or "mismatch" mark a worker set while the connection was down must
    // survive a reconnect, and the spec and assets need not travel again.
    const std::string jk = job_key(job.ej.id);
    conn_->cmd({"HSET", jk, "run", job.run, "cancelled", "0", "spec", job.ej.spec_json, "assets", job.manifest,
                "max_failures", std::to_string(cfg_.max_failures)});
    conn_->cmd({"HDEL", jk, "failed", "mismatch"});
    for (const auto& [rel, a] : job.assets) conn_->cmd({"SET", asset_key(a.sha256), a.bytes, "NX"});
    job.hash_written = true;
  }
  if (!job.cur.published) publish_pass(job, job.cur);
  if (job.ahead && !job.ahead->published) publish_pass(job, *job.ahead);
}

void RedisExecutor::publish_pass(Job& job, PassRun& pass) {
  const std::string& id = job.ej.id;
  const std::string s = pass_key('s', id, job.run, pass.work.pass);
  const std::string p = pass_key('p', id, job.run, pass.work.pass);
  const std::string r = pass_key('r', id, job.run, pass.work.pass);
  const size_t n = pass.work.blocks.size();
  // Entries already stored (a republish after a reconnect without a Redis restart) need
  // no new stream entry. A pass published for the first time has none: skip the round trip.
  std::set<size_t> have;  // first slots
  if (pass.was_published) {
    for (const RValue& k : conn_->cmd({"HKEYS", r}).elems) have.insert(static_cast<size_t>(k.as_int()));
  }
  if (pass.entries.empty()) plan_entries(job, pass);
  std::vector<std::pair<std::string, std::string>> entries;  // first slot, blocks
  size_t stored_blocks = 0;
  for (const auto& [first, count] : pass.entries) {
    if (have.count(first)) {
      stored_blocks += count;
      continue;
    }
    std::string bytes;
    for (size_t i = first; i < first + count; ++i) bytes += encode_block(pass.work.blocks[i]);
    entries.emplace_back(std::to_string(first), std::move(bytes));
  }
  // The whole pass in one round trip (workers without work wait until this lands).
  const std::string n_s = std::to_string(n), e_s = std::to_string(pass.entries.size());
  const std::string g_s = std::to_string(pass.group_blocks);
  conn_->append({"HSET", p, "n", n_s, "e", e_s, "input", pass.work.pass_input, "g", g_s});
  conn_->append({"DEL", s});
  conn_->append({"XGROUP", "CREATE", s, kGroup, "$", "MKSTREAM"});
  for (const auto& [first, bytes] : entries) conn_->append({"XADD", s, "*", "b", bytes, "s", first});
  conn_->append({"SADD", kActive, s});
  conn_->append({"XADD", kWake, "MAXLEN", "~", "1000", "*", "j", id});
  std::string error;
  for (size_t i = 0; i < entries.size() + 5; ++i) {
    const RValue v = conn_->get_reply();  // read every reply, even after an error
    if (v.type == RValue::Type::error && error.empty()) error = v.str;
  }
  if (!error.empty()) throw RedisReplyError("publishing a pass: " + error);
  std::lock_guard lock(mu_);
  if (pass.start == Clock::time_point{}) pass.start = Clock::now();
  pass.published = true;
  pass.was_published = true;
  if (&pass == &job.cur) job.blocks.pending = n - std::min(n, stored_blocks);
}

void RedisExecutor::plan_entries(const Job& job, PassRun& pass) {
  // Entry sizes by guided self-scheduling: each entry takes 1/(2T) of what is left (T:
  // live worker threads), at most ~20 ms and at least ~2 ms of work (from the workers'
  // measured time per block), so a pass starts with few big entries and ends with
  // small ones, and the last worker to finish waits for little. A pass with another
  // planned after it (PassWork::followed) needs no small tail (workers go on with the
  // next pass): its entries are equal, 1/(2T) of the pass (within the same bounds),
  // so there are fewer round trips per block. Entries end where a result group ends: a
  // worker combines each group's blocks and sends one result.
  size_t k_max = 1, k_min = 1, threads = 1;
  {
    std::lock_guard lock(mu_);
    unsigned t = 0;
    for (const auto& w : workers_) t += w.threads;
    threads = std::max(1u, t);
    if (job.block_seconds > 0) {
      k_max = static_cast<size_t>(std::clamp(0.02 / job.block_seconds, 1.0, 4096.0));
      k_min = static_cast<size_t>(std::clamp(0.002 / job.block_seconds, 1.0, 4096.0));
    }
    k_max = std::clamp<size_t>(k_max, 1, std::max<size_t>(1, cfg_.max_entry_blocks));
    k_min = std::min(k_min, k_max);
  }
  const std::vector<ResultGroup>& groups = pass.work.groups;
  const size_t n = pass.work.blocks.size();
  // The groups are the ones result_groups cuts with their largest size: a worker cuts
  // its entry's blocks the same way from that one number (the pass hash's "g").
  size_t g = 1, covered = 0;
  for (const ResultGroup& r : groups) {
    g = std::max(g, r.count);
    covered += r.count;
  }
  TALLY_CHECK_MSG(covered == n && result_groups(pass.work.blocks, g) == groups,
                  "pass {} of job {}: its result groups are not result_groups(blocks, {})", pass.work.pass, job.ej.id, g);
  std::vector<std::pair<size_t, size_t>> entries;
  std::vector<size_t> entry_groups;
  size_t largest = 1;
  for (size_t gi = 0; gi < groups.size();) {
    const size_t first = groups[gi].first;
    const size_t left = n - first;
    const size_t share = pass.work.followed ? n : left;  // of the pass, or of what is left
    const size_t want = std::min(left, std::clamp((share + 2 * threads - 1) / (2 * threads), k_min, k_max));
    size_t k = 0;
    entry_groups.push_back(gi);
    while (gi < groups.size() && (k == 0 || k + groups[gi].count <= want)) k += groups[gi++].count;
    entries.emplace_back(first, k);
    largest = std::max(largest, k);
  }
  std::lock_guard lock(mu_);
  pass.entries = std::move(entries);
  pass.entry_groups = std::move(entry_groups);
  pass.group_blocks = g;
  pass.entry_blocks = largest;
}

void RedisExecutor::poll(const std::vector<std::string>& ids) {
  struct Probe {
    std::string id, r, s, jk;
    size_t entries;  // result fields of a complete pass
  };
  std::vector<Probe> probes;
  {
    std::lock_guard lock(mu_);
    auto add_probe = [&](const Job& j) {
      if (!j.cur.published || j.cancel_requested) return;
      probes.push_back({j.ej.id, pass_key('r', j.ej.id, j.run, j.cur.work.pass),
                        pass_key('s', j.ej.id, j.run, j.cur.work.pass), job_key(j.ej.id), j.cur.entries.size()});
    };
    if (ids.empty()) {
      for (const auto& [id, j] : jobs_) add_probe(*j);
    } else {
      for (const auto& id : ids) {
        if (auto it = jobs_.find(id); it != jobs_.end()) add_probe(*it->second);
      }
    }
  }
  for (const Probe& pr : probes) {
    conn_->append({"HLEN", pr.r});
    conn_->append({"EXISTS", pr.s});
    conn_->append({"HMGET", pr.jk, "failed", "mismatch", "run"});
  }
  struct Outcome {
    std::string id;
    enum { nothing, merge, fail, republish } what = nothing;
    std::string error;
  };
  std::vector<Outcome> outcomes;
  for (const Probe& pr : probes) {
    const RValue hlen = conn_->get_reply();
    const RValue exists = conn_->get_reply();
    const RValue flags = conn_->get_reply();
    Outcome o;
    o.id = pr.id;
    if (flags.is_array() && flags.elems.size() == 3) {
      if (!flags.elems[0].is_nil()) {
        o.what = Outcome::fail;
        o.error = flags.elems[0].str;
      } else if (!flags.elems[1].is_nil()) {
        o.what = Outcome::fail;
        o.error = fmt::format(
            "non-determinism: two deliveries of the entry at block slot {} of a pass gave different results; the job "
            "cannot be trusted",
            flags.elems[1].str);
      } else if (flags.elems[2].is_nil()) {
        o.what = Outcome::republish;  // Redis lost the job (restart, flush)
      }
    }
    if (o.what == Outcome::nothing) {
      if (hlen.type == RValue::Type::integer && static_cast<size_t>(hlen.integer) >= pr.entries) {
        o.what = Outcome::merge;
      } else if (exists.type == RValue::Type::integer && exists.integer == 0) {
        o.what = Outcome::republish;
      }
    }
    outcomes.push_back(std::move(o));
  }
  for (const Outcome& o : outcomes) {
    switch (o.what) {
      case Outcome::merge: merge(o.id); break;
      case Outcome::fail:
        log::job(log::Level::error, o.id, "{}", o.error);
        leave(o.id, true, o.error);
        break;
      case Outcome::republish: {
        std::lock_guard lock(mu_);
        if (auto it = jobs_.find(o.id); it != jobs_.end()) {
          it->second->cur.published = false;
          if (it->second->ahead) it->second->ahead->published = false;
          it->second->hash_written = false;  // the job hash may be gone too
          counters_.republished++;
          log::job(log::Level::warn, o.id, "its pass vanished from Redis; republishing");
        }
        break;
      }
      case Outcome::nothing: break;
    }
  }
}

std::string RedisExecutor::read_results(Job& job, PassRun& run, bool prefetch, size_t& bytes) {
  const PassWork& pass = run.work;
  const size_t ng = pass.groups.size();
  if (run.got.size() != ng) {
    run.got.assign(ng, std::nullopt);
    run.got_count = 0;
  }
  const std::string r = pass_key('r', job.ej.id, job.run, pass.pass);
  std::vector<size_t> want;  // indices into run.entries
  auto entry_at = [&](size_t first) -> std::optional<size_t> {
    auto it = std::lower_bound(run.entries.begin(), run.entries.end(), std::make_pair(first, size_t{0}));
    if (it == run.entries.end() || it->first != first) return std::nullopt;
    return static_cast<size_t>(it - run.entries.begin());
  };
  if (prefetch) {
    const RValue keys = conn_->cmd({"HKEYS", r});
    for (const RValue& k : keys.elems) {
      size_t first = 0;
      try {
        first = static_cast<size_t>(k.as_int());
      } catch (const std::exception&) {
        return "a result field is not a slot number";
      }
      const auto e = entry_at(first);
      if (!e) return fmt::format("result field {} is not the first slot of an entry of the pass", first);
      if (!run.got[run.entry_groups[*e]]) want.push_back(*e);
    }
  } else {
    for (size_t e = 0; e < run.entries.size(); ++e) {
      if (!run.got[run.entry_groups[e]]) want.push_back(e);
    }
  }
  if (want.empty()) return {};
  std::vector<std::string> keys;
  for (size_t e : want) keys.push_back(value_key(job.ej.id, job.run, pass.pass, std::to_string(run.entries[e].first)));
  std::vector<std::string_view> argv = {"MGET"};
  for (const auto& k : keys) argv.push_back(k);
  const RValue v = conn_->cmd(argv);
  if (v.type == RValue::Type::error) throw RedisReplyError("MGET: " + v.str);
  for (size_t i = 0; i < want.size() && i < v.elems.size(); ++i) {
    if (v.elems[i].is_nil()) continue;
    const size_t e = want[i];
    const size_t first = run.entries[e].first;
    const size_t g0 = run.entry_groups[e];
    const size_t g1 = e + 1 < run.entry_groups.size() ? run.entry_groups[e + 1] : ng;
    std::vector<BlockResult> res;
    try {
      res = decode_entry_results(v.elems[i].str);
    } catch (const WireError& err) {
      return fmt::format("the results of the entry at block slot {} cannot be decoded: {}", first, err.what());
    }
    if (res.size() != g1 - g0) {
      return fmt::format("the entry at block slot {} has {} results, expected {} (one per result group)", first,
                         res.size(), g1 - g0);
    }
    for (size_t j = 0; j < res.size(); ++j) {
      const size_t slot = pass.groups[g0 + j].first;
      if (res[j].block_index != pass.blocks[slot].index) {
        return fmt::format("the result in slot {} belongs to block {}, expected {}", slot, res[j].block_index,
                           pass.blocks[slot].index);
      }
    }
    bytes += v.elems[i].str.size();
    run.bytes_read += v.elems[i].str.size();
    for (size_t j = 0; j < res.size(); ++j) run.got[g0 + j] = std::move(res[j]);
    run.got_count += res.size();
  }
  return {};
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
    std::string error = read_results(*job, job->cur, true, bytes);
    if (error.empty() && job->ahead && job->ahead->published) error = read_results(*job, *job->ahead, true, bytes);
    if (!error.empty()) {
      log::job(log::Level::error, id, "{}", error);
      leave(id, true, error);
    }
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
  const std::string error = read_results(*job, run, false, result_bytes);
  if (!error.empty() || run.got_count >= run.work.groups.size()) job->last_pass_bytes = run.bytes_read;
  if (!error.empty()) {
    log::job(log::Level::error, id, "{}", error);
    leave(id, true, error);
    return;
  }
  if (run.got_count < ng) return;  // not complete yet
  const double read_ms = ms_since(t_read);
  const RValue m = conn_->cmd({"HMGET", job_key(id), "compute_s", "computed"});
  const auto t_decode = Clock::now();
  std::vector<BlockResult> results(ng);
  for (size_t i = 0; i < ng; ++i) results[i] = std::move(*run.got[i]);
  run.got.clear();
  run.got_count = 0;
  const double decode_ms = ms_since(t_decode);
  const double wall = std::chrono::duration<double>(Clock::now() - run.start).count();
  {
    try {
      const double secs = m.elems.at(0).is_nil() ? 0.0 : std::stod(m.elems[0].str);
      const long long blocks = m.elems.at(1).as_int();
      if (secs > 0 && blocks > 0) job->block_seconds = secs / static_cast<double>(blocks);
    } catch (const std::exception& e) {
      log::job(log::Level::debug, id, "no block time measured yet ({}): entries stay one block long", e.what());
    }
  }
  // The pass is merged: its stream, inputs and results go. Digests stay a few passes
  // so a late duplicate is still compared.
  const std::string s = pass_key('s', id, job->run, pass.pass);
  size_t replies = 2;
  conn_->append({"SREM", kActive, s});
  {
    // One DEL: the index and the values go together (a store sees both or neither).
    std::vector<std::string> keys = {s, pass_key('p', id, job->run, pass.pass), pass_key('r', id, job->run, pass.pass),
                                     pass_key('f', id, job->run, pass.pass)};
    for (const auto& [first, count] : run.entries) {
      keys.push_back(value_key(id, job->run, pass.pass, std::to_string(first)));
    }
    std::vector<std::string_view> argv = {"DEL"};
    for (const auto& k : keys) argv.push_back(k);
    conn_->append(argv);
  }
  job->digest_passes.push_back(pass.pass);
  while (job->digest_passes.size() > cfg_.digest_passes) {
    conn_->append({"DEL", pass_key('d', id, job->run, job->digest_passes.front())});
    job->digest_passes.pop_front();
    ++replies;
  }
  for (size_t i = 0; i < replies; ++i) {
    const RValue v = conn_->get_reply();
    if (v.type == RValue::Type::error) log::job(log::Level::warn, id, "deleting a merged pass's keys: {}", v.str);
  }
  uint64_t samples = 0;
  for (const Block& b : pass.blocks) samples += b.sample_count;
  {
    std::lock_guard lock(mu_);
    counters_.merged += n;
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
  std::shared_ptr<const PassWork> after = std::move(next.ahead);
  bool adopted = false, restarted = false;
  if (job->ahead && same_plan(job->ahead->work, next)) {
    // The pass published ahead is the one planned: its results so far stand.
    adopted = true;
  } else if (job->ahead) {
    // Planned differently after all: what was computed for it must never be taken for
    // the new plan's blocks (same pass number), so the job continues as a new run and
    // the old run's keys are swept.
    restarted = true;
    log::job(log::Level::warn, id, "the pass published ahead ({}) differs from the pass planned; it is dropped",
             job->ahead->work.pass);
  }
  {
    std::lock_guard lock(mu_);
    if (adopted) {
      counters_.ahead++;
      job->cur = std::move(*job->ahead);
      job->ahead.reset();
      job->cur.start = Clock::now();  // its wall time starts when the pass before it ends
    } else {
      job->ahead.reset();
      job->cur = PassRun{};
      job->cur.work = std::move(next);
      if (restarted) {
        job->run = fmt::format("{}.{}", job->ej.epoch, ++generation_);
        job->swept = job->hash_written = false;
        job->digest_passes.clear();
      }
    }
    if (after) {
      job->ahead = std::make_unique<PassRun>();
      job->ahead->work = *after;
    }
    job->blocks = {};
    job->blocks.pending = job->cur.work.blocks.size();
  }
  if (job->cancel_requested) return;
  const auto t_publish = Clock::now();
  publish(*job);
  // The adopted pass may be complete already (its completion was announced while it was
  // ahead): look at it in the next step.
  if (adopted) conn_->cmd({"RPUSH", kNotify, id});
  // One line per pass boundary: where the coordinator's serial time goes.
  log::job(log::Level::debug, id,
           "pass {} ({} blocks, {} result groups, {} read before the end, {} result bytes read at the end): noticed "
           "{:.3f} ms after "
           "BLPOP returned, read + decode {:.3f} ms, collect {:.3f} ms, merge {:.3f} ms, publish {:.3f} ms ({} "
           "entries{}), boundary {:.3f} ms; at unix {:.6f}",
           pass_no, n, ng, had, result_bytes, std::chrono::duration<double, std::milli>(t_read - notified_at_).count(),
           read_ms, decode_ms, merge_ms, ms_since(t_publish), job->cur.entries.size(),
           adopted ? ", published ahead" : "",
           std::chrono::duration<double, std::milli>(Clock::now() - notified_at_).count(), unix_seconds());
}

void RedisExecutor::clean_finished() {
  while (!finished_.empty()) {
    delete_job_keys(*finished_.front());
    finished_.pop_front();
  }
}

void RedisExecutor::delete_pass_keys(const Job& job, uint64_t pass) {
  const std::string& id = job.ej.id;
  const std::string s = pass_key('s', id, job.run, pass);
  conn_->cmd({"SREM", kActive, s});
  // The job is marked cancelled before this runs: no store adds a value after the HKEYS.
  const std::string r = pass_key('r', id, job.run, pass);
  std::vector<std::string> keys = {s, pass_key('p', id, job.run, pass), r, pass_key('f', id, job.run, pass),
                                   pass_key('d', id, job.run, pass)};
  for (const RValue& slot : conn_->cmd({"HKEYS", r}).elems) keys.push_back(value_key(id, job.run, pass, slot.str));
  std::vector<std::string_view> argv = {"DEL"};
  for (const auto& k : keys) argv.push_back(k);
  conn_->cmd(argv);
}

void RedisExecutor::delete_job_keys(Job& job) {
  const std::string& id = job.ej.id;
  conn_->cmd({"HSET", job_key(id), "cancelled", "1"});
  delete_pass_keys(job, job.cur.work.pass);
  if (job.ahead) delete_pass_keys(job, job.ahead->work.pass);
  for (uint64_t p : job.digest_passes) conn_->cmd({"DEL", pass_key('d', id, job.run, p)});
  job.digest_passes.clear();
  conn_->cmd({"DEL", job_key(id)});
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
  const double now = unix_seconds();
  const double timeout = worker_timeout_s(cfg_.lease);
  conn_->cmd({"ZREMRANGEBYSCORE", kWorkers, "-inf", fmt::format("{}", now - 10 * timeout)});
  const RValue names = conn_->cmd({"ZRANGE", kWorkers, "0", "-1"});
  std::vector<WorkerInfo> ws;
  for (const RValue& name : names.elems) {
    const RValue h = conn_->cmd({"HMGET", worker_key(name.str), "host", "threads", "heartbeat", "blocks_done", "current_job"});
    if (!h.is_array() || h.elems.size() != 5 || h.elems[2].is_nil()) continue;
    WorkerInfo w;
    w.name = name.str;
    w.host = h.elems[0].str;
    try {
      w.threads = static_cast<unsigned>(h.elems[1].as_int());
      w.last_heartbeat = std::stod(h.elems[2].str);
      w.blocks_done = static_cast<uint64_t>(h.elems[3].as_int());
    } catch (const std::exception&) {
      continue;  // a malformed registry entry is not a live worker
    }
    w.current_job = h.elems[4].str;
    if (now - w.last_heartbeat > timeout) continue;
    ws.push_back(std::move(w));
  }
  const RValue c = conn_->cmd({"HMGET", kCounters, "first", "dup_equal", "dup_differ", "stale", "failures"});

  // Per job: blocks in flight (pending entries) and redelivered.
  struct Probe {
    std::string id, s, jk, p;
    uint64_t n, k;
  };
  std::vector<Probe> probes;
  {
    std::lock_guard lock(mu_);
    for (const auto& [id, j] : jobs_) {
      if (j->cur.published) {
        probes.push_back({id, pass_key('s', id, j->run, j->cur.work.pass), job_key(id),
                          pass_key('p', id, j->run, j->cur.work.pass), j->cur.work.blocks.size(), j->cur.entry_blocks});
      }
    }
  }
  std::map<std::string, ExecutorStats::JobBlocks> flight;
  for (const Probe& p : probes) {
    conn_->append({"XPENDING", p.s, kGroup});
    conn_->append({"HGET", p.jk, "redelivered"});
    conn_->append({"HGET", p.p, "done"});
    conn_->append({"XPENDING", p.s, kGroup, "-", "+", "50"});
  }
  // Entries delivered again and again without a result: the workers that took them died
  // or stalled each time (a crash on that block, not a thrown error). Give up on the job
  // rather than loop forever; one delivery more than --max-deliveries allows one stall.
  std::vector<std::pair<std::string, std::string>> crashed;
  for (const Probe& p : probes) {
    const RValue pend = conn_->get_reply();
    const RValue red = conn_->get_reply();
    const RValue stored = conn_->get_reply();
    const RValue detail = conn_->get_reply();
    for (const RValue& e : detail.elems) {
      if (e.elems.size() < 4 || e.elems[3].type != RValue::Type::integer) continue;
      if (static_cast<uint64_t>(e.elems[3].integer) > static_cast<uint64_t>(cfg_.max_failures) + 1) {
        crashed.emplace_back(p.id, fmt::format("an entry of blocks was delivered {} times and no worker finished it "
                                               "(last held by {}): the workers crash or stall on it",
                                               e.elems[3].integer, e.elems[1].str));
        break;
      }
    }
    uint64_t inflight = 0;
    if (pend.is_array() && !pend.elems.empty() && pend.elems[0].type == RValue::Type::integer) {
      inflight = static_cast<uint64_t>(pend.elems[0].integer);
    }
    const uint64_t redelivered = static_cast<uint64_t>(red.to_int().value_or(0));
    const uint64_t done = static_cast<uint64_t>(stored.to_int().value_or(0));
    ExecutorStats::JobBlocks b;
    b.in_flight = std::min<uint64_t>(p.n - std::min<uint64_t>(p.n, done), inflight * p.k);
    b.redelivered = redelivered;
    b.pending = p.n > done + b.in_flight ? p.n - done - b.in_flight : 0;
    flight[p.id] = b;
  }
  std::unique_lock lock(mu_);
  workers_ = std::move(ws);
  if (c.is_array() && c.elems.size() == 5) {
    auto v = [&](size_t i) -> uint64_t { return static_cast<uint64_t>(c.elems[i].to_int().value_or(0)); };
    counters_.first = v(0);
    counters_.dup_equal = v(1);
    counters_.dup_differ = v(2);
    counters_.stale = v(3);
    counters_.failures = v(4);
  }
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
