#include "server/cluster/worker.hpp"

#include <fmt/format.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <deque>
#include <fstream>
#include <map>
#include <memory>
#include <mutex>
#include <thread>
#include <vector>

#include "common/protocol/job_kinds.hpp"
#include "common/spec/spec_reader.hpp"
#include "server/cluster/assets.hpp"
#include "server/cluster/cluster_store.hpp"
#include "server/cluster/result_key.hpp"
#include "server/cluster/wire.hpp"

namespace tally::cluster {

namespace {

using Clock = std::chrono::steady_clock;
using namespace std::chrono_literals;

struct Held {
  std::string stream, entry, consumer, job;
};

struct Compiled {
  std::shared_ptr<const JobDefinition> def;
  std::shared_ptr<const Kernel> kernel;
  std::string error;  // non-empty: the spec was refused here
};

// The order a thread tries the active streams in: jobs in turn (starting at a rotating
// one, so jobs share the workers), and within a job its earlier pass first (a pass
// published ahead is computed once the current one has no entry left to hand out).
std::vector<std::string> reading_order(const std::vector<std::string>& streams, size_t rotate) {
  std::map<std::string, std::vector<std::pair<uint64_t, std::string>>> by_job;
  for (const std::string& s : streams) {
    const auto sk = parse_stream_key(s);
    by_job[sk ? sk->id : s].emplace_back(sk ? sk->pass : 0, s);
  }
  std::vector<std::vector<std::pair<uint64_t, std::string>>*> jobs;
  for (auto& [id, passes] : by_job) {
    std::sort(passes.begin(), passes.end());
    jobs.push_back(&passes);
  }
  std::vector<std::string> order;
  for (size_t i = 0; i < jobs.size(); ++i) {
    for (const auto& [pass, s] : *jobs[(rotate + i) % jobs.size()]) order.push_back(s);
  }
  return order;
}

// Whether every active stream belongs to one job.
bool one_job_only(const std::vector<std::string>& streams) {
  std::optional<std::string> job;
  for (const std::string& s : streams) {
    const auto sk = parse_stream_key(s);
    if (!sk || (job && *job != sk->id)) return false;
    job = sk->id;
  }
  return true;
}

double unix_seconds() {
  return std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
}

class Worker {
 public:
  Worker(const WorkerConfig& cfg, const std::atomic<bool>& stop) : cfg_(cfg), stop_(stop), held_(cfg.threads) {}

  int run() {
    std::vector<std::thread> threads;
    for (unsigned t = 0; t < cfg_.threads; ++t) threads.emplace_back([this, t] { compute_loop(t); });
    heartbeat_loop();
    for (auto& th : threads) th.join();
    return 0;
  }

 private:
  void log(const std::string& msg) {
    std::lock_guard lock(log_mu_);
    fmt::print("tally-worker {}: {}\n", cfg_.name, msg);
    std::fflush(stdout);
  }

  std::chrono::milliseconds lease() const { return std::chrono::milliseconds(lease_ms_.load()); }

  // ------------------------------------------------------------ heartbeat

  void heartbeat_loop() {
    std::unique_ptr<RedisConn> conn;
    std::string keep_sha;
    while (!stop_) {
      try {
        if (!conn) {
          conn = std::make_unique<RedisConn>(cfg_.url);
          keep_sha = conn->load_script(kKeepLeaseScript);
        }
        beat(*conn, keep_sha);
      } catch (const std::exception& e) {
        if (conn) log(fmt::format("heartbeat: {}", e.what()));
        conn.reset();
      }
      const auto period = std::clamp(lease() / 3, std::chrono::milliseconds(100), std::chrono::milliseconds(1000));
      const auto until = Clock::now() + period;
      while (!stop_ && Clock::now() < until) std::this_thread::sleep_for(100ms);  // a stop is seen within 0.1 s
    }
    // Leave the registry at once so the coordinator stops counting this worker.
    try {
      if (!conn) conn = std::make_unique<RedisConn>(cfg_.url, 1000ms);
      leave_registry(*conn, cfg_.name);
    } catch (const std::exception& e) {
      log(fmt::format("could not leave the registry ({}); the entry expires by itself", e.what()));
    }
  }

  void beat(RedisConn& conn, const std::string& keep_sha) {
    if (auto v = read_lease_ms(conn)) lease_ms_ = std::max<long long>(100, *v);
    std::vector<Held> held;
    {
      std::lock_guard lock(mu_);
      for (const auto& h : held_) {
        if (!h.entry.empty()) held.push_back(h);
      }
    }
    for (const Held& h : held) keep_lease(conn, keep_sha, h.stream, h.entry, h.consumer);
    const double now = unix_seconds();
    WorkerRecord w;
    w.name = cfg_.name;
    w.host = cfg_.host;
    w.threads = cfg_.threads;
    w.pools = cfg_.pools;
    w.last_heartbeat = now;
    w.blocks_done = blocks_done_.load();
    if (!held.empty()) w.current_job = held.front().job;
    write_heartbeat(conn, w, std::max<long long>(60, 10 * lease_ms_.load() / 1000));
    if (!cfg_.health_file.empty()) std::ofstream(cfg_.health_file, std::ios::trunc) << fmt::format("{:.3f}\n", now);
  }

  // ------------------------------------------------------------ compute

  void compute_loop(unsigned t) {
    const std::string consumer = fmt::format("{}/{}", cfg_.name, t);
    std::unique_ptr<RedisConn> conn;
    std::string store_sha, fail_sha, wake_id;
    size_t rotate = t;
    auto last_claim = Clock::now() - 1h;
    bool warned = false;
    // The active streams, read again at most every 20 ms while there is work (a round
    // trip per entry saved), and at once when none of them has an entry left.
    std::vector<std::string> streams;
    auto streams_at = Clock::now() - 1h;
    while (!stop_) {
      try {
        if (!conn) {
          conn = std::make_unique<RedisConn>(cfg_.url);
          store_sha = conn->load_script(kStoreScript);
          fail_sha = conn->load_script(kFailScript);
          wake_id = last_wake_id(*conn);
          if (warned) log("connected to redis again");
          warned = false;
        }
        const bool fresh = Clock::now() - streams_at >= 20ms;
        if (fresh) {
          streams = active_streams(*conn, cfg_.pools);
          streams_at = Clock::now();
        }
        bool worked = false;
        // Reclaim blocks whose lease expired (a killed or stalled worker's).
        if (!streams.empty() && Clock::now() - last_claim >= lease() / 4) {
          last_claim = Clock::now();
          for (size_t si = 0; si < streams.size() && !worked; ++si) {
            const std::string& s = streams[si];
            // XAUTOCLAIM looks at 10 x COUNT pending entries per call: follow the cursor.
            std::string cursor = "0-0";
            for (int scan = 0; scan < 20 && !worked; ++scan) {
              const Reclaim r = reclaim_entry(*conn, s, consumer, lease_ms_.load(), cursor);
              if (!r.ok) break;
              if (r.entry) {
                process(conn, t, consumer, s, *r.entry, true, store_sha, fail_sha);
                worked = true;
              }
              cursor = r.cursor;
              if (cursor == "0-0") break;
            }
          }
        }
        if (!worked) {
          const std::vector<std::string> order = reading_order(streams, rotate);
          // One job's passes alone: the stream an entry came from is read on with each
          // store (one round trip per entry, not two) until it has no entry left (a
          // pass gets no entries after its publication, so its earlier pass is drained
          // already). With several jobs, each entry is read in the rotating order (jobs
          // share the threads).
          const bool one_job = one_job_only(streams);
          for (size_t i = 0; i < order.size() && !worked; ++i) {
            const std::string& s = order[i];
            if (const std::optional<StreamEntry> entry = read_entry(*conn, s, consumer)) {
              std::optional<StreamEntry> next;
              process(conn, t, consumer, s, *entry, false, store_sha, fail_sha, one_job ? &next : nullptr);
              while (next) {  // claimed: computed even when stopping
                const StreamEntry e = std::move(*next);
                next.reset();
                process(conn, t, consumer, s, e, false, store_sha, fail_sha, &next, true);
              }
              worked = true;
            }
          }
          ++rotate;
        }
        if (!worked && !fresh) {
          streams_at = Clock::now() - 1h;  // nothing left in the remembered streams: look again
          continue;
        }
        if (!worked) {
          // Idle: wait for the coordinator to announce work, at most a quarter lease
          // (then look for expired leases again).
          const auto wait = std::clamp(lease() / 4, std::chrono::milliseconds(20), std::chrono::milliseconds(500));
          if (auto woke = wait_wake(*conn, wait, wake_id)) {
            wake_id = std::move(*woke);
            if (cfg_.verbose) log(fmt::format("thread {} woken at unix {:.6f}", t, unix_seconds()));
          }
        }
      } catch (const RedisIoError& e) {
        if (!warned) log(fmt::format("redis unreachable ({}); retrying", e.what()));
        warned = true;
        conn.reset();
        for (int i = 0; i < 25 && !stop_; ++i) std::this_thread::sleep_for(20ms);
      } catch (const std::exception& e) {
        log(fmt::format("unexpected: {}", e.what()));
        for (int i = 0; i < 10 && !stop_; ++i) std::this_thread::sleep_for(20ms);
      }
    }
  }

  Compiled compile(RedisConn& conn, const StreamKey& sk) {
    const std::string tag = sk.id + "_" + sk.run;
    std::lock_guard lock(compile_mu_);
    if (auto it = kernels_.find(tag); it != kernels_.end()) return it->second;
    Compiled c;
    const JobSource src = read_job_source(conn, sk.id);
    try {
      if (!src.spec) throw std::runtime_error("the job's spec is missing from Redis");
      if (!cfg_.result_key.empty() &&
          !same_digest(src.spec_mac, spec_mac(cfg_.result_key, sk.id, sk.run, *src.spec, src.manifest))) {
        throw std::runtime_error("the job's spec in Redis does not match its MAC (--result-key-file): it was written "
                                 "by someone without the cluster's key, or the server's key differs from this "
                                 "worker's; refused");
      }
      const nlohmann::json spec = nlohmann::json::parse(*src.spec);
      JobLimits limits = cfg_.limits;
      limits.asset_dir.clear();  // only the job's own assets, never a local directory
      limits.asset_store = (cfg_.cache_dir / "blobs").string();  // "sha256:" names: verified blobs only
      if (!src.manifest.empty()) {
        const nlohmann::json manifest = nlohmann::json::parse(src.manifest);
        if (!manifest.empty()) limits.asset_dir = materialize_assets(conn, manifest, cfg_.cache_dir, tag).string();
      }
      std::shared_ptr<const JobDefinition> def = compile_job(spec, limits);
      c.kernel = def->kernel();
      if (cfg_.wrap_kernel) c.kernel = cfg_.wrap_kernel(c.kernel);
      c.def = std::move(def);
    } catch (const SpecError& e) {
      c.error = fmt::format("the worker refused the spec: {} (at {})", e.detail(), e.pointer());
    } catch (const RedisIoError&) {
      throw;  // lost the connection while fetching assets: retry later, do not cache a failure
    } catch (const std::exception& e) {
      c.error = fmt::format("the worker could not compile the spec: {}", e.what());
    }
    kernels_[tag] = c;
    kernel_order_.push_back(tag);
    while (kernel_order_.size() > 8) {
      kernels_.erase(kernel_order_.front());
      std::error_code ec;
      std::filesystem::remove_all(cfg_.cache_dir / "jobs" / kernel_order_.front(), ec);
      kernel_order_.pop_front();
    }
    return c;
  }

  // The job's max_failures if `run` is its current run and it is not cancelled, else
  // nullopt. A yes is remembered for 20 ms (a round trip per entry saved; an entry of a
  // job cancelled meanwhile is computed and then counted stale by the store script); a
  // no, or a run not seen yet, is always asked again.
  std::optional<std::string> live_run(RedisConn& conn, const std::string& id, const std::string& run) {
    {
      std::lock_guard lock(mu_);
      if (auto it = live_.find(id); it != live_.end() && it->second.run == run && Clock::now() - it->second.at < 20ms) {
        return it->second.max_failures;
      }
    }
    return note_live(id, run, read_run_state(conn, id));
  }
  // What live_run answers from the job's run state `st`, remembered (a yes) or
  // forgotten (a no).
  std::optional<std::string> note_live(const std::string& id, const std::string& run, const std::optional<RunState>& st) {
    std::lock_guard lock(mu_);
    if (!st || st->run != run || st->cancelled) {
      live_.erase(id);
      return std::nullopt;
    }
    LiveRun l{run, st->max_failures.value_or("3"), Clock::now()};
    if (live_.size() > 64) live_.clear();
    live_[id] = l;
    return l.max_failures;
  }

  std::optional<PassMeta> pass_meta(RedisConn& conn, const StreamKey& sk) {
    const PassKeys keys(sk.id, sk.run, sk.pass);
    const std::string& p = keys.meta;
    {
      std::lock_guard lock(mu_);
      if (auto it = metas_.find(p); it != metas_.end()) return it->second;
    }
    const std::optional<PassMeta> m = read_pass_meta(conn, keys);
    if (!m) return std::nullopt;
    std::lock_guard lock(mu_);
    metas_[p] = *m;
    meta_order_.push_back(p);
    while (meta_order_.size() > 64) {
      metas_.erase(meta_order_.front());
      meta_order_.pop_front();
    }
    return m;
  }

  // Runs a result-storing script (store_entry, fail_entry); if the connection drops
  // (Redis restarted, a proxy or CLIENT KILL closed it), reconnects and runs it again for
  // a few seconds rather than dropping computed blocks; uploads again if Redis lost the
  // upload between the two commands (a restart). Both scripts are idempotent: a repeat
  // of a store that did land counts as an equal duplicate; a repeat of a failure is
  // ignored unless the entry is still pending.
  // Runs `call` on the connection, reconnecting (for up to 5 s, unless stopping) when
  // the connection is lost, and again when the store script says its upload is missing.
  template <class Call>
  auto retrying(std::unique_ptr<RedisConn>& conn, Call&& call) {
    const auto deadline = Clock::now() + 5s;
    bool oom_logged = false;
    for (;;) {
      try {
        if (!conn) conn = std::make_unique<RedisConn>(cfg_.url);
        return call(*conn);
      } catch (const RedisIoError& e) {
        conn.reset();
        if (stop_ || Clock::now() >= deadline) throw;
        log(fmt::format("storing results: {}; reconnecting to store them", e.what()));
        std::this_thread::sleep_for(100ms);
      } catch (const RedisReplyError& e) {
        const std::string_view what = e.what();
        if (what.find("OOM ") != std::string_view::npos && !stop_) {
          // Redis is out of memory: keep the computed results (the heartbeat keeps the
          // entry's lease) and store them once it has room; the coordinator says why
          // the job waits. Logged once per episode.
          if (!oom_logged) log(fmt::format("storing results: {}; holding them until Redis has memory", what));
          oom_logged = true;
          std::this_thread::sleep_for(200ms);
          continue;
        }
        if (!what.starts_with(kUploadMissing) || stop_ || Clock::now() >= deadline) throw;
        log(fmt::format("storing results: {}; uploading them again", e.what()));
      }
    }
  }

  // Computes and stores one entry. `next` (if given and not stopping): the store also
  // reads the stream's next entry for this thread (store_entry's ReadOn), and whether
  // the job is still live (live_run's question, answered for the next entry's
  // live_run). `read_on`: this entry was read so, by the store before it (the verbose
  // log says so).
  void process(std::unique_ptr<RedisConn>& conn_owner, unsigned t, const std::string& consumer,
               const std::string& stream, const StreamEntry& entry, bool redelivered, const std::string& store_sha,
               const std::string& fail_sha, std::optional<StreamEntry>* next = nullptr, bool read_on = false) {
    RedisConn& conn = *conn_owner;
    const auto t_got = Clock::now();
    const double unix_got = unix_seconds();
    const std::string& entry_id = entry.id;
    const std::string& block_bytes = entry.blocks;
    const std::string& slot = entry.slot;
    const auto sk = parse_stream_key(stream);
    if (!sk || slot.empty()) {
      log(fmt::format("ignoring a malformed entry {} of {}", entry_id, stream));
      skip_entry(conn, stream, entry_id);
      return;
    }
    const std::optional<std::string> max_failures = live_run(conn, sk->id, sk->run);
    if (!max_failures) {
      skip_entry(conn, stream, entry_id);  // cancelled or an older run: skip
      return;
    }
    if (redelivered) count_redelivery(conn, sk->id);
    const Compiled c = compile(conn, *sk);
    const auto meta = pass_meta(conn, *sk);
    if (!meta) {
      skip_entry(conn, stream, entry_id);  // the pass is gone (merged)
      return;
    }
    {
      std::lock_guard lock(mu_);
      held_[t] = Held{stream, entry_id, consumer, sk->id};
    }
    std::string results;  // the entry's results, one hash field (append_entry_result)
    size_t block_count = 0;
    std::string error;
    uint64_t block_index = 0;
    const auto t0 = Clock::now();
    const double prep_ms = std::chrono::duration<double, std::milli>(t0 - t_got).count();
    try {
      const std::vector<Block> blocks = decode_blocks(block_bytes);
      if (!c.error.empty()) throw std::runtime_error(c.error);
      // One result per result group: its blocks combined in block order, as the
      // coordinator's JobRunner would combine them (the same bits as in process).
      for (const ResultGroup& g : result_groups(blocks, meta->group_blocks)) {
        BlockResult group;
        for (size_t i = g.first; i < g.first + g.count; ++i) {
          block_index = blocks[i].index;
          BlockResult out;
          out.block_index = blocks[i].index;
          c.kernel->run_block_with(blocks[i], meta->input, out);
          if (i == g.first) {
            group = std::move(out);
          } else {
            combine_results(group, out);
          }
        }
        append_entry_result(results, encode_result(group));
      }
      block_count = blocks.size();
    } catch (const std::exception& e) {
      error = fmt::format("block {} (slot {}) of job {} failed on worker {}: {}", block_index, slot, sk->id, cfg_.name,
                          e.what());
    }
    const double secs = std::chrono::duration<double>(Clock::now() - t0).count();
    {
      std::lock_guard lock(mu_);
      held_[t] = Held{};
    }
    const PassKeys keys(sk->id, sk->run, sk->pass);
    if (!error.empty()) {
      const EntryFailure f{&keys, sk->id, sk->run, entry_id, slot, *max_failures, error, block_bytes};
      const long long r = retrying(conn_owner, [&](RedisConn& rc) { return fail_entry(rc, fail_sha, f); });
      log(fmt::format("{}{}", error, r == 2 ? " (delivery limit reached: the job fails)" : " (re-queued)"));
      return;
    }
    const std::string digest = entry_digest(cfg_.result_key, sk->id, sk->run, sk->pass, slot, results);
    const size_t bytes = results.size();
    const std::string upload = upload_key(consumer);
    const EntryStore store{&keys, sk->id, sk->run, slot, entry_id, upload, meta->entries, secs, block_count, digest,
                           results};
    ReadOn read_next{stream, consumer, sk->id, std::nullopt, std::nullopt};
    ReadOn* const read_on_store = stop_ || !next ? nullptr : &read_next;
    const auto t_store = Clock::now();
    const StoreOutcome r = retrying(conn_owner, [&](RedisConn& rc) {
      StoreOutcome o = store_entry(rc, store_sha, store, read_on_store);
      if (read_on_store && read_next.run) note_live(sk->id, sk->run, read_next.run);
      return o;
    });
    if (read_next.entry) *next = std::move(read_next.entry);
    const double store_ms = std::chrono::duration<double, std::milli>(Clock::now() - t_store).count();
    blocks_done_.fetch_add(block_count);
    if (r.dup_equal > 0) {
      log(fmt::format("duplicate result for {} block(s) from slot {} of job {} pass {}: compared, identical",
                      r.dup_equal, slot, sk->id, sk->pass));
    }
    if (r.dup_differ > 0) {
      log(fmt::format("duplicate result for slot {} of job {} pass {} DIFFERS from the first: non-determinism", slot,
                      sk->id, sk->pass));
    }
    if (cfg_.verbose) {
      log(fmt::format("entry {} of job {} pass {}: first {} stale {}; {} blocks, {} result bytes; got at unix {:.6f} "
                      "{}, prepare {:.3f} ms, compute {:.3f} ms, store {:.3f} ms",
                      slot, sk->id, sk->pass, r.first, r.stale, block_count, bytes, unix_got,
                      read_on ? "with the store before" : "by a read of its own", prep_ms, secs * 1e3, store_ms));
    }
  }

  const WorkerConfig& cfg_;
  const std::atomic<bool>& stop_;
  std::mutex log_mu_, compile_mu_, mu_;
  std::vector<Held> held_;
  std::map<std::string, Compiled> kernels_;
  std::deque<std::string> kernel_order_;
  std::map<std::string, PassMeta> metas_;
  struct LiveRun {
    std::string run, max_failures;
    Clock::time_point at;
  };
  std::map<std::string, LiveRun> live_;  // job key -> its run, lately confirmed live
  std::deque<std::string> meta_order_;
  std::atomic<uint64_t> blocks_done_{0};
  std::atomic<long long> lease_ms_{30000};
};

}  // namespace

int run_worker(const WorkerConfig& config, const std::atomic<bool>& stop) {
  Worker w(config, stop);
  return w.run();
}

}  // namespace tally::cluster
