#include "server/cluster/cluster_store.hpp"

#include <fmt/format.h>

#include <charconv>

namespace tally::cluster {

std::optional<StreamKey> parse_stream_key(std::string_view k) {
  // tally:s:{id}:{run}:{pass}
  if (!k.starts_with("tally:s:")) return std::nullopt;
  const std::string_view rest = k.substr(8);
  const size_t a = rest.find(':');
  const size_t b = a == std::string_view::npos ? a : rest.find(':', a + 1);
  if (a == std::string_view::npos || b == std::string_view::npos || a == 0) return std::nullopt;
  StreamKey s;
  s.id = std::string(rest.substr(0, a));
  s.run = std::string(rest.substr(a + 1, b - a - 1));
  const std::string_view digits = rest.substr(b + 1);
  if (digits.empty() || digits.front() == '-' || digits.front() == '+') return std::nullopt;
  const auto [end, ec] = std::from_chars(digits.data(), digits.data() + digits.size(), s.pass);
  if (ec != std::errc() || end != digits.data() + digits.size()) return std::nullopt;
  return s;
}

namespace {

RValue checked(RValue v, std::string_view what) {
  if (v.type == RValue::Type::error) throw RedisReplyError(fmt::format("{}: {}", what, v.str));
  return v;
}

// The entry of an XREADGROUP ... COUNT 1 or XAUTOCLAIM reply element [id, [field, value...]].
std::optional<StreamEntry> entry_from(const RValue& e) {
  if (!e.is_array() || e.elems.size() != 2 || !e.elems[1].is_array()) return std::nullopt;
  StreamEntry out;
  out.id = e.elems[0].str;
  const auto& fv = e.elems[1].elems;
  for (size_t i = 0; i + 1 < fv.size(); i += 2) {
    if (fv[i].str == "b") out.blocks = fv[i + 1].str;
    if (fv[i].str == "s") out.slot = fv[i + 1].str;
  }
  return out;
}

// The entry an XREADGROUP ... COUNT 1 reply hands out, or nullopt (none, an error reply:
// the stream or its group is gone).
std::optional<StreamEntry> entry_of(const RValue& r) {
  if (!r.is_array() || r.elems.empty() || !r.elems[0].is_array() || r.elems[0].elems.size() != 2 ||
      r.elems[0].elems[1].elems.empty()) {
    return std::nullopt;
  }
  return entry_from(r.elems[0].elems[1].elems[0]);
}

std::optional<RunState> run_state_of(const RValue& st) {
  if (st.elems.size() != 3) return std::nullopt;
  RunState s;
  s.run = st.elems[0].str;
  s.cancelled = st.elems[1].str == "1";
  if (!st.elems[2].is_nil()) s.max_failures = st.elems[2].str;
  return s;
}

// A command on a stream that may vanish (merged, cancelled): an error reply (NOGROUP)
// reads as nil.
RValue on_stream(RedisConn& conn, const std::vector<std::string_view>& argv) {
  try {
    return conn.cmd(argv);
  } catch (const RedisReplyError&) {
    return {};
  }
}

std::string join(const std::vector<std::string>& v) {
  std::string s;
  for (const auto& x : v) s += (s.empty() ? "" : ",") + x;
  return s;
}

std::vector<std::string> split(std::string_view s) {
  std::vector<std::string> out;
  while (!s.empty()) {
    const size_t c = s.find(',');
    if (c != 0) out.emplace_back(s.substr(0, c));
    if (c == std::string_view::npos) break;
    s.remove_prefix(c + 1);
  }
  return out;
}

}  // namespace

// ---------------------------------------------------------------- coordinator

void announce_lease(RedisConn& conn, std::chrono::milliseconds lease) {
  conn.cmd({"HSET", kConfig, "lease_ms", std::to_string(lease.count())});
}

void clear_active_sets(RedisConn& conn) {
  conn.cmd({"DEL", kActive});
  const std::string pattern = std::string(kActive) + ":*";
  std::string cursor = "0";
  do {
    const RValue r = conn.cmd({"SCAN", cursor, "MATCH", pattern, "COUNT", "1000"});
    if (!r.is_array() || r.elems.size() != 2) break;
    cursor = r.elems[0].str;
    for (const RValue& k : r.elems[1].elems) conn.cmd({"DEL", k.str});
  } while (cursor != "0");
}

void push_wake_marker(RedisConn& conn) { conn.cmd({"RPUSH", kNotify, kWakeMarker}); }

void notify_job(RedisConn& conn, std::string_view id) { conn.cmd({"RPUSH", kNotify, id}); }

Notified wait_notified(RedisConn& conn, std::string_view timeout_s) {
  Notified n;
  const RValue r = conn.cmd({"BLPOP", kNotify, timeout_s});
  if (r.is_array() && r.elems.size() == 2) {
    n.woken = true;
    if (r.elems[1].str != kWakeMarker) n.jobs.push_back(r.elems[1].str);
    const RValue more = conn.cmd({"LPOP", kNotify, "1000"});
    for (const RValue& m : more.elems) {
      if (m.str != kWakeMarker) n.jobs.push_back(m.str);
    }
  }
  return n;
}

void sweep_other_runs(RedisConn& conn, std::string_view id, std::string_view run, std::string_view active) {
  const std::string pattern = fmt::format("tally:?:{}:*", id);
  const std::string this_run = fmt::format(":{}:", run);
  std::string cursor = "0";
  do {
    const RValue r = conn.cmd({"SCAN", cursor, "MATCH", pattern, "COUNT", "1000"});
    if (!r.is_array() || r.elems.size() != 2) break;
    cursor = r.elems[0].str;
    for (const RValue& k : r.elems[1].elems) {
      if (k.str.find(this_run) != std::string::npos) continue;
      conn.cmd({"DEL", k.str});
      conn.cmd({"SREM", active, k.str});
    }
  } while (cursor != "0");
}

void write_job(RedisConn& conn, const JobRecord& job, const std::map<std::string, JobAsset>& assets) {
  const std::string jk = job_key(job.id);
  conn.cmd({"HSET", jk, "run", job.run, "cancelled", "0", "spec", job.spec, "assets", job.manifest, "spec_mac",
            job.spec_mac, "max_failures", std::to_string(job.max_failures)});
  conn.cmd({"HDEL", jk, "failed", "mismatch"});
  for (const auto& [rel, a] : assets) conn.cmd({"SET", asset_key(a.sha256), a.bytes, "NX"});
}

std::vector<std::string> stored_entry_slots(RedisConn& conn, const PassKeys& pass) {
  std::vector<std::string> out;
  for (RValue& k : conn.cmd({"HKEYS", pass.index}).elems) out.push_back(std::move(k.str));
  return out;
}

void publish_pass(RedisConn& conn, const PassKeys& keys, std::string_view active, std::string_view id,
                  const PassPublication& pub) {
  const std::string n_s = std::to_string(pub.blocks), e_s = std::to_string(pub.entries);
  const std::string g_s = std::to_string(pub.group_blocks);
  conn.append({"HSET", keys.meta, "n", n_s, "e", e_s, "input", pub.input, "g", g_s});
  conn.append({"DEL", keys.stream});
  conn.append({"XGROUP", "CREATE", keys.stream, kGroup, "$", "MKSTREAM"});
  for (const auto& [first, bytes] : pub.new_entries) conn.append({"XADD", keys.stream, "*", "b", bytes, "s", first});
  conn.append({"SADD", active, keys.stream});
  conn.append({"XADD", kWake, "MAXLEN", "~", "1000", "*", "j", id});
  std::string error;
  for (size_t i = 0; i < pub.new_entries.size() + 5; ++i) {
    const RValue v = conn.get_reply();  // read every reply, even after an error
    if (v.type == RValue::Type::error && error.empty()) error = v.str;
  }
  if (!error.empty()) throw RedisReplyError("publishing a pass: " + error);
}

std::vector<PassState> probe_passes(RedisConn& conn, const std::vector<PassProbe>& probes) {
  for (const PassProbe& p : probes) {
    conn.append({"HLEN", p.keys->index});
    conn.append({"EXISTS", p.keys->stream});
    conn.append({"HMGET", p.job_key, "failed", "mismatch", "run"});
  }
  std::vector<PassState> out;
  for (size_t i = 0; i < probes.size(); ++i) {
    const RValue hlen = conn.get_reply();
    const RValue exists = conn.get_reply();
    const RValue flags = conn.get_reply();
    PassState s;
    if (hlen.type == RValue::Type::integer) s.entries_stored = hlen.integer;
    if (exists.type == RValue::Type::integer) s.stream_exists = exists.integer != 0;
    if (flags.is_array() && flags.elems.size() == 3) {
      s.job_hash_read = true;
      if (!flags.elems[0].is_nil()) s.failed = flags.elems[0].str;
      if (!flags.elems[1].is_nil()) s.mismatch = flags.elems[1].str;
      if (!flags.elems[2].is_nil()) s.run = flags.elems[2].str;
    }
    out.push_back(std::move(s));
  }
  return out;
}

std::vector<StoredEntry> read_entry_values(RedisConn& conn, const PassKeys& pass, const std::vector<size_t>& first_slots) {
  std::vector<std::string> keys, slots;
  for (size_t first : first_slots) {
    keys.push_back(pass.value(first));
    slots.push_back(std::to_string(first));
  }
  std::vector<std::string_view> argv = {"MGET"};
  for (const auto& k : keys) argv.push_back(k);
  conn.append(argv);
  argv = {"HMGET", pass.digests};
  for (const auto& s : slots) argv.push_back(s);
  conn.append(argv);
  RValue v = conn.get_reply();
  RValue d = conn.get_reply();
  checked(v, "MGET");
  checked(d, "HMGET digests");
  std::vector<StoredEntry> out(first_slots.size());
  for (size_t i = 0; i < out.size(); ++i) {
    if (i < v.elems.size() && !v.elems[i].is_nil()) out[i].results = std::move(v.elems[i].str);
    if (i < d.elems.size() && !d.elems[i].is_nil()) out[i].digest = std::move(d.elems[i].str);
  }
  return out;
}

double measured_block_seconds(RedisConn& conn, std::string_view id) {
  const RValue m = conn.cmd({"HMGET", job_key(id), "compute_s", "computed"});
  const double secs = m.elems.at(0).is_nil() ? 0.0 : std::stod(m.elems[0].str);
  const long long blocks = m.elems.at(1).as_int();
  return secs > 0 && blocks > 0 ? secs / static_cast<double>(blocks) : 0.0;
}

std::vector<std::string> drop_merged_pass(RedisConn& conn, const PassKeys& pass, std::string_view active,
                                          const std::vector<size_t>& entry_slots,
                                          const std::vector<PassKeys>& old_digests) {
  conn.append({"SREM", active, pass.stream});
  std::vector<std::string> keys = {pass.stream, pass.meta, pass.index, pass.failures};
  for (size_t first : entry_slots) keys.push_back(pass.value(first));
  std::vector<std::string_view> argv = {"DEL"};
  for (const auto& k : keys) argv.push_back(k);
  conn.append(argv);
  for (const PassKeys& d : old_digests) conn.append({"DEL", d.digests});
  std::vector<std::string> errors;
  for (size_t i = 0; i < 2 + old_digests.size(); ++i) {
    const RValue v = conn.get_reply();
    if (v.type == RValue::Type::error) errors.push_back(v.str);
  }
  return errors;
}

void delete_job(RedisConn& conn, std::string_view id, const std::vector<PassKeys>& passes,
                const std::vector<PassKeys>& digests, std::string_view active) {
  conn.cmd({"HSET", job_key(id), "cancelled", "1"});
  for (const PassKeys& pass : passes) {
    conn.cmd({"SREM", active, pass.stream});
    // The job is marked cancelled before this runs: no store adds a value after the HKEYS.
    std::vector<std::string> keys = {pass.stream, pass.meta, pass.index, pass.failures, pass.digests};
    for (const RValue& slot : conn.cmd({"HKEYS", pass.index}).elems) keys.push_back(pass.value(slot.str));
    std::vector<std::string_view> argv = {"DEL"};
    for (const auto& k : keys) argv.push_back(k);
    conn.cmd(argv);
  }
  for (const PassKeys& d : digests) conn.cmd({"DEL", d.digests});
  conn.cmd({"DEL", job_key(id)});
}

std::vector<PassFlight> probe_flight(RedisConn& conn, const std::vector<PassProbe>& probes) {
  for (const PassProbe& p : probes) {
    conn.append({"XPENDING", p.keys->stream, kGroup});
    conn.append({"HGET", p.job_key, "redelivered"});
    conn.append({"HGET", p.keys->meta, "done"});
    conn.append({"XPENDING", p.keys->stream, kGroup, "-", "+", "50"});
  }
  std::vector<PassFlight> out;
  for (size_t i = 0; i < probes.size(); ++i) {
    const RValue pend = conn.get_reply();
    const RValue red = conn.get_reply();
    const RValue stored = conn.get_reply();
    const RValue detail = conn.get_reply();
    PassFlight f;
    for (const RValue& e : detail.elems) {
      if (e.elems.size() < 4 || e.elems[3].type != RValue::Type::integer) continue;
      f.oldest.push_back({e.elems[3].integer, e.elems[1].str});
    }
    if (pend.is_array() && !pend.elems.empty() && pend.elems[0].type == RValue::Type::integer) {
      f.entries_pending = static_cast<uint64_t>(pend.elems[0].integer);
    }
    f.redelivered = static_cast<uint64_t>(red.to_int().value_or(0));
    f.blocks_done = static_cast<uint64_t>(stored.to_int().value_or(0));
    out.push_back(std::move(f));
  }
  return out;
}

RedisMemory read_memory(RedisConn& conn) {
  const RValue info = conn.cmd({"INFO", "memory"});
  RedisMemory m;
  auto field = [&](std::string_view name) -> uint64_t {
    const std::string key = std::string(name) + ":";
    size_t at = info.str.find(key);
    while (at != std::string::npos && at != 0 && info.str[at - 1] != '\n') at = info.str.find(key, at + 1);
    if (at == std::string::npos) return 0;
    uint64_t v = 0;
    const char* b = info.str.data() + at + key.size();
    std::from_chars(b, info.str.data() + info.str.size(), v);
    return v;
  };
  m.used = field("used_memory");
  m.max = field("maxmemory");
  return m;
}

std::optional<StoreCounters> read_store_counters(RedisConn& conn) {
  const RValue c = conn.cmd({"HMGET", kCounters, "first", "dup_equal", "dup_differ", "stale", "failures"});
  if (!c.is_array() || c.elems.size() != 5) return std::nullopt;
  auto v = [&](size_t i) -> uint64_t { return static_cast<uint64_t>(c.elems[i].to_int().value_or(0)); };
  return StoreCounters{v(0), v(1), v(2), v(3), v(4)};
}

std::vector<WorkerRecord> read_worker_registry(RedisConn& conn, double forget_before) {
  conn.cmd({"ZREMRANGEBYSCORE", kWorkers, "-inf", fmt::format("{}", forget_before)});
  const RValue names = conn.cmd({"ZRANGE", kWorkers, "0", "-1"});
  std::vector<WorkerRecord> ws;
  for (const RValue& name : names.elems) {
    const RValue h =
        conn.cmd({"HMGET", worker_key(name.str), "host", "threads", "heartbeat", "blocks_done", "current_job", "pools"});
    if (!h.is_array() || h.elems.size() != 6 || h.elems[2].is_nil()) continue;
    WorkerRecord w;
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
    w.pools = split(h.elems[5].str);
    ws.push_back(std::move(w));
  }
  return ws;
}

// ---------------------------------------------------------------- worker

std::optional<long long> read_lease_ms(RedisConn& conn) { return conn.cmd({"HGET", kConfig, "lease_ms"}).to_int(); }

bool keep_lease(RedisConn& conn, const std::string& sha, std::string_view stream, std::string_view entry,
                std::string_view consumer) {
  return conn.evalsha(sha, kKeepLeaseScript, {stream}, {entry, consumer}).to_int().value_or(0) == 1;
}

void write_heartbeat(RedisConn& conn, const WorkerRecord& w, long long ttl_s) {
  const std::string wk = worker_key(w.name);
  const std::string beat = fmt::format("{:.3f}", w.last_heartbeat);
  conn.cmd({"HSET", wk, "name", w.name, "host", w.host, "threads", std::to_string(w.threads), "heartbeat", beat,
            "blocks_done", std::to_string(w.blocks_done), "current_job", w.current_job, "pools", join(w.pools)});
  conn.cmd({"EXPIRE", wk, std::to_string(ttl_s)});
  conn.cmd({"ZADD", kWorkers, beat, w.name});
}

void leave_registry(RedisConn& conn, std::string_view name) {
  conn.cmd({"ZREM", kWorkers, name});
  conn.cmd({"DEL", worker_key(name)});
}

std::string last_wake_id(RedisConn& conn) {
  const RValue last = conn.cmd({"XREVRANGE", kWake, "+", "-", "COUNT", "1"});
  return last.is_array() && !last.elems.empty() ? last.elems[0].elems[0].str : "0-0";
}

std::optional<std::string> wait_wake(RedisConn& conn, std::chrono::milliseconds wait, std::string_view after) {
  const RValue r = conn.cmd({"XREAD", "COUNT", "100", "BLOCK", std::to_string(wait.count()), "STREAMS", kWake, after});
  if (r.is_array() && !r.elems.empty() && r.elems[0].elems.size() == 2 && !r.elems[0].elems[1].elems.empty()) {
    return r.elems[0].elems[1].elems.back().elems[0].str;
  }
  return std::nullopt;
}

std::vector<std::string> active_streams(RedisConn& conn, const std::vector<std::string>& pools) {
  std::vector<std::string> sets;
  for (const auto& p : pools) sets.push_back(active_key(p));
  std::vector<std::string_view> argv = {pools.empty() ? "SMEMBERS" : "SUNION", kActive};
  for (const auto& s : sets) argv.push_back(s);
  std::vector<std::string> out;
  for (RValue& v : conn.cmd(argv).elems) out.push_back(std::move(v.str));
  return out;
}

std::optional<StreamEntry> read_entry(RedisConn& conn, std::string_view stream, std::string_view consumer) {
  return entry_of(on_stream(conn, {"XREADGROUP", "GROUP", kGroup, consumer, "COUNT", "1", "STREAMS", stream, ">"}));
}

Reclaim reclaim_entry(RedisConn& conn, std::string_view stream, std::string_view consumer, long long idle_ms,
                      std::string_view cursor) {
  const RValue r =
      on_stream(conn, {"XAUTOCLAIM", stream, kGroup, consumer, std::to_string(idle_ms), cursor, "COUNT", "1"});
  Reclaim out;
  if (!r.is_array() || r.elems.size() < 2) return out;
  out.ok = true;
  if (!r.elems[1].elems.empty()) out.entry = entry_from(r.elems[1].elems[0]);
  out.cursor = r.elems[0].str;
  return out;
}

void skip_entry(RedisConn& conn, std::string_view stream, std::string_view entry_id) {
  on_stream(conn, {"XACK", stream, kGroup, entry_id});
}

void count_redelivery(RedisConn& conn, std::string_view id) { conn.cmd({"HINCRBY", job_key(id), "redelivered", "1"}); }

JobSource read_job_source(RedisConn& conn, std::string_view id) {
  const RValue h = conn.cmd({"HMGET", job_key(id), "spec", "assets", "spec_mac"});
  JobSource s;
  if (h.elems.size() != 3) return s;
  if (!h.elems[0].is_nil()) s.spec = h.elems[0].str;
  if (!h.elems[1].is_nil()) s.manifest = h.elems[1].str;
  if (!h.elems[2].is_nil()) s.spec_mac = h.elems[2].str;
  return s;
}

std::optional<RunState> read_run_state(RedisConn& conn, std::string_view id) {
  return run_state_of(conn.cmd({"HMGET", job_key(id), "run", "cancelled", "max_failures"}));
}

std::optional<PassMeta> read_pass_meta(RedisConn& conn, const PassKeys& pass) {
  const RValue h = conn.cmd({"HMGET", pass.meta, "e", "input", "g"});
  if (h.elems.size() != 3 || h.elems[0].is_nil()) return std::nullopt;
  PassMeta m;
  m.entries = static_cast<uint64_t>(h.elems[0].as_int());
  m.input = h.elems[1].str;
  if (!h.elems[2].is_nil()) m.group_blocks = static_cast<uint64_t>(std::max<long long>(1, h.elems[2].as_int()));
  return m;
}

StoreOutcome store_entry(RedisConn& c, const std::string& sha, const EntryStore& e, ReadOn* read_on) {
  const bool inline_results = e.results.size() < kUploadBytes;
  const std::string jk = job_key(e.job_id), value = e.keys->value(e.slot);
  const std::string entries = std::to_string(e.pass_entries);
  const std::string secs = fmt::format("{:.9f}", e.compute_seconds);
  const std::string k = std::to_string(e.blocks);
  const std::vector<std::string_view> keys = {e.keys->index, e.keys->stream, jk,        e.keys->digests, kCounters,
                                              kNotify,       e.keys->meta,   e.upload,  value};
  const std::string nkeys = std::to_string(keys.size());
  std::vector<std::string_view> argv = {"EVALSHA", sha, nkeys};
  argv.insert(argv.end(), keys.begin(), keys.end());
  for (std::string_view a : {e.slot, e.entry_id, e.run, std::string_view(entries), e.job_id, std::string_view(secs),
                             std::string_view(k), e.digest}) {
    argv.push_back(a);
  }
  if (inline_results) argv.push_back(e.results);
  const std::string next_jk = read_on ? job_key(read_on->job_id) : std::string();
  bool reloaded = false;
  for (;;) {
    if (!inline_results) c.append({"SET", e.upload, e.results, "PX", kUploadTtlMs});
    c.append(argv);
    const bool read_next = read_on && !read_on->entry;
    if (read_next) {
      c.append({"XREADGROUP", "GROUP", kGroup, read_on->consumer, "COUNT", "1", "STREAMS", read_on->stream, ">"});
      c.append({"HMGET", next_jk, "run", "cancelled", "max_failures"});
    }
    const RValue set = inline_results ? RValue{} : c.get_reply();
    RValue r = c.get_reply();
    if (read_next) {
      read_on->entry = entry_of(c.get_reply());  // an error reply (the pass is gone) reads nothing
      read_on->run = run_state_of(c.get_reply());
    }
    if (set.type == RValue::Type::error) throw RedisReplyError("SET: " + set.str);
    if (r.type == RValue::Type::error && r.str.find("NOSCRIPT") != std::string::npos && !reloaded) {
      c.load_script(kStoreScript);  // Redis restarted and forgot it: same source, same SHA1
      reloaded = true;
      continue;
    }
    if (r.type == RValue::Type::error) throw RedisReplyError(r.str);
    StoreOutcome o;
    if (r.elems.size() == 4) o = {r.elems[0].integer, r.elems[1].integer, r.elems[2].integer, r.elems[3].integer};
    return o;
  }
}

long long fail_entry(RedisConn& conn, const std::string& sha, const EntryFailure& f) {
  const std::string jk = job_key(f.job_id);
  return conn
      .evalsha(sha, kFailScript, {f.keys->stream, jk, f.keys->failures, kCounters, kNotify, kWake},
               {f.entry_id, f.slot, f.run, f.max_failures, f.message, f.blocks, f.job_id})
      .as_int();
}

std::optional<std::string> read_asset(RedisConn& conn, std::string_view sha) {
  RValue r = conn.cmd({"GET", asset_key(sha)});
  if (r.is_nil()) return std::nullopt;
  return std::move(r.str);
}

}  // namespace tally::cluster
