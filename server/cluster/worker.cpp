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
#include "server/cluster/protocol.hpp"
#include "server/cluster/wire.hpp"

namespace tally::cluster {

namespace {

using Clock = std::chrono::steady_clock;
using namespace std::chrono_literals;

// Resets the idle time of an entry this consumer still holds (never steals one that
// was reclaimed by another worker meanwhile).
constexpr std::string_view kKeepLeaseScript = R"lua(
local p = redis.call('XPENDING', KEYS[1], 'w', ARGV[1], ARGV[1], 1, ARGV[2])
if #p == 1 then
  redis.call('XCLAIM', KEYS[1], 'w', ARGV[2], 0, ARGV[1], 'JUSTID')
  return 1
end
return 0
)lua";

struct Held {
  std::string stream, entry, consumer, job;
};

struct Compiled {
  std::shared_ptr<const JobDefinition> def;
  std::shared_ptr<const Kernel> kernel;
  std::string error;  // non-empty: the spec was refused here
};

struct PassMeta {
  uint64_t entries = 0;  // stream entries the pass is cut into (its result fields)
  std::string input;
  uint64_t group_blocks = 1;  // result groups: result_groups(an entry's blocks, this)
};

struct StreamKey {
  std::string id, run;
  uint64_t pass = 0;
};

std::optional<StreamKey> parse_stream_key(const std::string& k) {
  // tally:s:{id}:{run}:{pass}
  if (!k.starts_with("tally:s:")) return std::nullopt;
  const std::string rest = k.substr(8);
  const size_t a = rest.find(':');
  const size_t b = a == std::string::npos ? a : rest.find(':', a + 1);
  if (a == std::string::npos || b == std::string::npos || a == 0) return std::nullopt;
  StreamKey s;
  s.id = rest.substr(0, a);
  s.run = rest.substr(a + 1, b - a - 1);
  try {
    size_t used = 0;
    s.pass = std::stoull(rest.substr(b + 1), &used);
    if (used != rest.size() - b - 1) return std::nullopt;
  } catch (const std::exception&) {
    return std::nullopt;
  }
  return s;
}

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

// The entry an XREADGROUP ... COUNT 1 reply hands out, or null (none, an error reply:
// the stream or its group is gone).
const RValue* entry_of(const RValue& r) {
  if (!r.is_array() || r.elems.empty() || !r.elems[0].is_array() || r.elems[0].elems.size() != 2 ||
      r.elems[0].elems[1].elems.empty()) {
    return nullptr;
  }
  const RValue& e = r.elems[0].elems[1].elems[0];
  return e.is_array() && e.elems.size() == 2 && e.elems[1].is_array() ? &e : nullptr;
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
      conn->cmd({"ZREM", kWorkers, cfg_.name});
      conn->cmd({"DEL", worker_key(cfg_.name)});
    } catch (const std::exception& e) {
      log(fmt::format("could not leave the registry ({}); the entry expires by itself", e.what()));
    }
  }

  void beat(RedisConn& conn, const std::string& keep_sha) {
    const RValue l = conn.cmd({"HGET", "tally:config", "lease_ms"});
    if (auto v = l.to_int()) lease_ms_ = std::max<long long>(100, *v);
    std::vector<Held> held;
    {
      std::lock_guard lock(mu_);
      for (const auto& h : held_) {
        if (!h.entry.empty()) held.push_back(h);
      }
    }
    for (const Held& h : held) {
      conn.evalsha(keep_sha, kKeepLeaseScript, {h.stream}, {h.entry, h.consumer});
    }
    const double now = unix_seconds();
    const std::string wk = worker_key(cfg_.name);
    conn.cmd({"HSET", wk, "name", cfg_.name, "host", cfg_.host, "threads", std::to_string(cfg_.threads), "heartbeat",
              fmt::format("{:.3f}", now), "blocks_done", std::to_string(blocks_done_.load()), "current_job",
              held.empty() ? std::string() : held.front().job});
    conn.cmd({"EXPIRE", wk, std::to_string(std::max<long long>(60, 10 * lease_ms_.load() / 1000))});
    conn.cmd({"ZADD", kWorkers, fmt::format("{:.3f}", now), cfg_.name});
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
          const RValue last = conn->cmd({"XREVRANGE", kWake, "+", "-", "COUNT", "1"});
          wake_id = last.is_array() && !last.elems.empty() ? last.elems[0].elems[0].str : "0-0";
          if (warned) log("connected to redis again");
          warned = false;
        }
        const bool fresh = Clock::now() - streams_at >= 20ms;
        if (fresh) {
          const RValue active = conn->cmd({"SMEMBERS", kActive});
          streams.clear();
          for (const RValue& v : active.elems) streams.push_back(v.str);
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
              const RValue r = try_cmd(*conn, {"XAUTOCLAIM", s, kGroup, consumer, std::to_string(lease_ms_.load()),
                                               cursor, "COUNT", "1"});
              if (!r.is_array() || r.elems.size() < 2) break;
              if (!r.elems[1].elems.empty()) {
                const RValue& e = r.elems[1].elems[0];
                if (e.is_array() && e.elems.size() == 2 && e.elems[1].is_array()) {
                  process(conn, t, consumer, s, e, true, store_sha, fail_sha);
                  worked = true;
                }
              }
              cursor = r.elems[0].str;
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
            const RValue r = try_cmd(*conn, {"XREADGROUP", "GROUP", kGroup, consumer, "COUNT", "1", "STREAMS", s, ">"});
            if (const RValue* entry = entry_of(r)) {
              std::optional<RValue> next;
              process(conn, t, consumer, s, *entry, false, store_sha, fail_sha, one_job ? &next : nullptr);
              while (next) {  // claimed: computed even when stopping
                const RValue e = std::move(*next);
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
          const RValue r = conn->cmd({"XREAD", "COUNT", "100", "BLOCK", std::to_string(wait.count()), "STREAMS", kWake, wake_id});
          if (r.is_array() && !r.elems.empty() && r.elems[0].elems.size() == 2 && !r.elems[0].elems[1].elems.empty()) {
            wake_id = r.elems[0].elems[1].elems.back().elems[0].str;
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

  // A command on a stream that may vanish (merged, cancelled): NOGROUP is not an error.
  static RValue try_cmd(RedisConn& conn, const std::vector<std::string_view>& argv) {
    try {
      return conn.cmd(argv);
    } catch (const RedisReplyError&) {
      return {};
    }
  }

  Compiled compile(RedisConn& conn, const StreamKey& sk) {
    const std::string tag = sk.id + "_" + sk.run;
    std::lock_guard lock(compile_mu_);
    if (auto it = kernels_.find(tag); it != kernels_.end()) return it->second;
    Compiled c;
    const RValue h = conn.cmd({"HMGET", job_key(sk.id), "spec", "assets"});
    try {
      if (h.elems.size() != 2 || h.elems[0].is_nil()) throw std::runtime_error("the job's spec is missing from Redis");
      const nlohmann::json spec = nlohmann::json::parse(h.elems[0].str);
      JobLimits limits = cfg_.limits;
      limits.asset_dir.clear();  // only the job's own assets, never a local directory
      limits.asset_store = (cfg_.cache_dir / "blobs").string();  // "sha256:" names: verified blobs only
      if (!h.elems[1].is_nil() && !h.elems[1].str.empty()) {
        const nlohmann::json manifest = nlohmann::json::parse(h.elems[1].str);
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
  std::optional<std::string> live_run(RedisConn& conn, const std::string& jk, const std::string& run) {
    {
      std::lock_guard lock(mu_);
      if (auto it = live_.find(jk); it != live_.end() && it->second.run == run && Clock::now() - it->second.at < 20ms) {
        return it->second.max_failures;
      }
    }
    return note_live(jk, run, conn.cmd({"HMGET", jk, "run", "cancelled", "max_failures"}));
  }
  // What live_run answers from the reply `st` to HMGET jk run cancelled max_failures,
  // remembered (a yes) or forgotten (a no).
  std::optional<std::string> note_live(const std::string& jk, const std::string& run, const RValue& st) {
    std::lock_guard lock(mu_);
    if (st.elems.size() != 3 || st.elems[0].str != run || st.elems[1].str == "1") {
      live_.erase(jk);
      return std::nullopt;
    }
    LiveRun l{run, st.elems[2].is_nil() ? std::string("3") : st.elems[2].str, Clock::now()};
    if (live_.size() > 64) live_.clear();
    live_[jk] = l;
    return l.max_failures;
  }

  std::optional<PassMeta> pass_meta(RedisConn& conn, const StreamKey& sk) {
    const std::string p = pass_key('p', sk.id, sk.run, sk.pass);
    {
      std::lock_guard lock(mu_);
      if (auto it = metas_.find(p); it != metas_.end()) return it->second;
    }
    const RValue h = conn.cmd({"HMGET", p, "e", "input", "g"});
    if (h.elems.size() != 3 || h.elems[0].is_nil()) return std::nullopt;
    PassMeta m;
    m.entries = static_cast<uint64_t>(h.elems[0].as_int());
    m.input = h.elems[1].str;
    if (!h.elems[2].is_nil()) m.group_blocks = static_cast<uint64_t>(std::max<long long>(1, h.elems[2].as_int()));
    std::lock_guard lock(mu_);
    metas_[p] = m;
    meta_order_.push_back(p);
    while (meta_order_.size() > 64) {
      metas_.erase(meta_order_.front());
      meta_order_.pop_front();
    }
    return m;
  }

  // Runs a result-storing script; if the connection drops (Redis restarted, a proxy or
  // CLIENT KILL closed it), reconnects and runs it again for a few seconds rather than
  // dropping computed blocks. Both scripts are idempotent: a repeat of a store that did
  // land counts as an equal duplicate; a repeat of a failure is ignored unless the entry
  // is still pending.
  RValue eval_retrying(std::unique_ptr<RedisConn>& conn, const std::string& sha, std::string_view source,
                       const std::vector<std::string_view>& keys, const std::vector<std::string_view>& args) {
    return retrying(conn, [&](RedisConn& c) { return c.evalsha(sha, source, keys, args); });
  }

  // Stores an entry's results with the store script (protocol.hpp): inline below
  // kUploadBytes, else SET at this thread's upload key first, in the same round trip (a
  // pipeline), for the script to move into place. Retried as eval_retrying; uploads
  // again if Redis lost the upload between the two commands (a restart).
  //
  // `next` (if given): the same round trip also reads the next entry of `next->stream`
  // for this consumer (XREADGROUP after the script), set if there is one (at most one is
  // read over the retries), and whether the job is still live (live_run's question,
  // answered for the next entry's live_run).
  struct ReadNext {
    std::string_view stream, consumer, job_key, run;
    std::optional<RValue> entry;
  };
  RValue store_retrying(std::unique_ptr<RedisConn>& conn, const std::string& sha, const std::string& upload,
                        std::string_view results, const std::vector<std::string_view>& keys,
                        const std::vector<std::string_view>& args, ReadNext* next = nullptr) {
    const bool inline_results = results.size() < kUploadBytes;
    const std::string nkeys = std::to_string(keys.size());
    std::vector<std::string_view> argv = {"EVALSHA", sha, nkeys};
    argv.insert(argv.end(), keys.begin(), keys.end());
    argv.insert(argv.end(), args.begin(), args.end());
    if (inline_results) argv.push_back(results);
    bool reloaded = false;
    return retrying(conn, [&](RedisConn& c) {
      for (;;) {
        if (!inline_results) c.append({"SET", upload, results, "PX", kUploadTtlMs});
        c.append(argv);
        const bool read_next = next && !next->entry;
        if (read_next) {
          c.append({"XREADGROUP", "GROUP", kGroup, next->consumer, "COUNT", "1", "STREAMS", next->stream, ">"});
          c.append({"HMGET", next->job_key, "run", "cancelled", "max_failures"});
        }
        const RValue set = inline_results ? RValue{} : c.get_reply();
        RValue r = c.get_reply();
        if (read_next) {
          const RValue x = c.get_reply();  // an error reply (the pass is gone) reads nothing
          if (const RValue* e = entry_of(x)) next->entry = *e;
          note_live(std::string(next->job_key), std::string(next->run), c.get_reply());
        }
        if (set.type == RValue::Type::error) throw RedisReplyError("SET: " + set.str);
        if (r.type == RValue::Type::error && r.str.find("NOSCRIPT") != std::string::npos && !reloaded) {
          c.load_script(kStoreScript);  // Redis restarted and forgot it: same source, same SHA1
          reloaded = true;
          continue;
        }
        if (r.type == RValue::Type::error) throw RedisReplyError(r.str);
        return r;
      }
    });
  }

  // Runs `call` on the connection, reconnecting (for up to 5 s, unless stopping) when
  // the connection is lost, and again when the store script says its upload is missing.
  template <class Call>
  RValue retrying(std::unique_ptr<RedisConn>& conn, Call&& call) {
    const auto deadline = Clock::now() + 5s;
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
        if (!std::string_view(e.what()).starts_with(kUploadMissing) || stop_ || Clock::now() >= deadline) throw;
        log(fmt::format("storing results: {}; uploading them again", e.what()));
      }
    }
  }

  // Computes and stores one entry. `next` (if given and not stopping): the store also
  // reads the stream's next entry for this thread (store_retrying). `read_on`: this
  // entry was read so, by the store before it (the verbose log says so).
  void process(std::unique_ptr<RedisConn>& conn_owner, unsigned t, const std::string& consumer,
               const std::string& stream, const RValue& entry, bool redelivered, const std::string& store_sha,
               const std::string& fail_sha, std::optional<RValue>* next = nullptr, bool read_on = false) {
    RedisConn& conn = *conn_owner;
    const auto t_got = Clock::now();
    const double unix_got = unix_seconds();
    const std::string& entry_id = entry.elems[0].str;
    std::string block_bytes, slot;
    const auto& fv = entry.elems[1].elems;
    for (size_t i = 0; i + 1 < fv.size(); i += 2) {
      if (fv[i].str == "b") block_bytes = fv[i + 1].str;
      if (fv[i].str == "s") slot = fv[i + 1].str;
    }
    const auto sk = parse_stream_key(stream);
    if (!sk || slot.empty()) {
      log(fmt::format("ignoring a malformed entry {} of {}", entry_id, stream));
      try_cmd(conn, {"XACK", stream, kGroup, entry_id});
      return;
    }
    const std::string jk = job_key(sk->id);
    const std::optional<std::string> max_failures = live_run(conn, jk, sk->run);
    if (!max_failures) {
      try_cmd(conn, {"XACK", stream, kGroup, entry_id});  // cancelled or an older run: skip
      return;
    }
    if (redelivered) conn.cmd({"HINCRBY", jk, "redelivered", "1"});
    const Compiled c = compile(conn, *sk);
    const auto meta = pass_meta(conn, *sk);
    if (!meta) {
      try_cmd(conn, {"XACK", stream, kGroup, entry_id});  // the pass is gone (merged)
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
    if (!error.empty()) {
      const RValue r = eval_retrying(conn_owner, fail_sha, kFailScript,
                                     {stream, jk, pass_key('f', sk->id, sk->run, sk->pass), kCounters, kNotify, kWake},
                                     {entry_id, slot, sk->run, *max_failures, error, block_bytes, sk->id});
      log(fmt::format("{}{}", error, r.as_int() == 2 ? " (delivery limit reached: the job fails)" : " (re-queued)"));
      return;
    }
    const std::string entries = std::to_string(meta->entries);
    const std::string secs_s = fmt::format("{:.9f}", secs);
    const std::string k = std::to_string(block_count);
    const std::string digest = result_digest(results);
    const size_t bytes = results.size();
    const std::vector<std::string_view> args = {slot, entry_id, sk->run, entries, sk->id, secs_s, k, digest};
    const std::string upload = upload_key(consumer);
    ReadNext read_next{stream, consumer, jk, sk->run, std::nullopt};
    const auto t_store = Clock::now();
    const RValue r = store_retrying(conn_owner, store_sha, upload, results,
                                    {pass_key('r', sk->id, sk->run, sk->pass), stream, jk,
                                     pass_key('d', sk->id, sk->run, sk->pass), kCounters, kNotify,
                                     pass_key('p', sk->id, sk->run, sk->pass), upload,
                                     value_key(sk->id, sk->run, sk->pass, slot)},
                                    args, stop_ || !next ? nullptr : &read_next);
    if (read_next.entry) *next = std::move(read_next.entry);
    const double store_ms = std::chrono::duration<double, std::milli>(Clock::now() - t_store).count();
    blocks_done_.fetch_add(block_count);
    if (r.elems.size() == 4) {
      if (r.elems[1].integer > 0) {
        log(fmt::format("duplicate result for {} block(s) from slot {} of job {} pass {}: compared, identical",
                        r.elems[1].integer, slot, sk->id, sk->pass));
      }
      if (r.elems[2].integer > 0) {
        log(fmt::format("duplicate result for slot {} of job {} pass {} DIFFERS from the first: non-determinism", slot,
                        sk->id, sk->pass));
      }
      if (cfg_.verbose) {
        log(fmt::format("entry {} of job {} pass {}: first {} stale {}; {} blocks, {} result bytes; got at unix {:.6f} "
                        "{}, prepare {:.3f} ms, compute {:.3f} ms, store {:.3f} ms",
                        slot, sk->id, sk->pass, r.elems[0].integer, r.elems[3].integer, block_count, bytes, unix_got,
                        read_on ? "with the store before" : "by a read of its own", prep_ms, secs * 1e3, store_ms));
      }
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
