// Cluster mode figures, from one run (build with -DTALLY_BUILD_BENCH=ON, then
// build/bench/cluster/cluster_bench). Starts its own redis-server on a Unix socket.
//  1. Overhead at equal cores: the same job on tally-server --workers 2 (in process) and
//     on tally-server --redis with one tally-worker --threads 2, interleaved A B B A ...
//     (argv[1] pairs, default 9); the median of the pairs' ratios with its spread and the
//     load average (goal: Redis <= 1.03x). Integration (the unit disk, ~30 us per block;
//     a 6-D expression, ~20x the work per block) and the lighting image, grey as in
//     examples/ and in colour.
//  2. Coordinator ceiling: a RedisExecutor driven directly with one-sample blocks (trivial
//     work) and 2 worker threads: blocks/s published and merged, with one block per entry
//     (worst case) and with the default entry sizing.
//  3. Reclaim latency after kill -9 of a worker holding an entry (lease 1 s; goal <=
//     lease + 1 s), and the duplicate ratio of that run.
//  4. Preemption latency (issue 32): a priority-5 submit just after a pass boundary of
//     the running low-priority image job; its start against that pass ("preemption" alone).
#include <fmt/format.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cstdlib>
#include <chrono>
#include <condition_variable>
#include <fcntl.h>
#include <fstream>
#include <iterator>
#include <sstream>
#include <mutex>
#include <thread>

#include "common/protocol/job_kinds.hpp"
#include "server/cluster/redis_layout.hpp"
#include "server/cluster/redis_executor.hpp"
#include "server_process.hpp"

using namespace tally;
using namespace tally::e2e;
using nlohmann::json;
using namespace std::chrono_literals;
namespace fs = std::filesystem;

namespace {

void reap(pid_t pid) {
  if (pid <= 0) return;
  ::kill(pid, SIGKILL);
  int st = 0;
  ::waitpid(pid, &st, 0);
}
pid_t worker(const std::string& url, const std::string& name, unsigned threads, const fs::path& dir) {
  return spawn_logged({TALLY_WORKER_BIN, "--redis", url, "--name", name, "--threads", std::to_string(threads)},
               dir / (name + ".log"));
}

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0.0 : v[v.size() / 2];
}

double job_wall(HttpClient& c, const json& spec, json* bits) {
  const std::string id = submit(c, spec);
  const json s = wait_state(c, id, "succeeded", 600);
  if (bits) *bits = s.at("bits");
  return s.at("timing").at("wall_seconds").get<double>();
}

// CPU seconds (user + system) a process has used so far, from /proc/<pid>/stat.
double cpu_seconds(pid_t pid) {
  std::ifstream in(fmt::format("/proc/{}/stat", pid));
  std::string stat((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const size_t close = stat.rfind(')');
  if (close == std::string::npos) return 0.0;
  std::istringstream fields(stat.substr(close + 2));
  std::string f;
  double ticks = 0;
  for (int i = 3; i <= 15 && fields >> f; ++i) {
    if (i == 14 || i == 15) ticks += std::stod(f);  // utime, stime
  }
  return ticks / static_cast<double>(::sysconf(_SC_CLK_TCK));
}
double cpu_seconds(const std::vector<pid_t>& pids) {
  double s = 0;
  for (pid_t p : pids) s += cpu_seconds(p);
  return s;
}

double load1() {
  double l[1] = {0};
  return ::getloadavg(l, 1) == 1 ? l[0] : -1.0;
}

// `rounds` alternations A B / B A ...: each pair's ratio B/A is measured seconds apart,
// so a change of the machine's load hits both sides of a pair alike. Prints the median
// pair ratio with its spread (min, quartiles, max) and the load average around it.
//
// CPU: the CPU seconds of the processes each side needs (in process: the server; cluster:
// server + worker + redis-server) per job, which the machine's load hardly changes. At
// equal, saturated cores the wall ratio tends to the CPU ratio.
void overhead(const std::string& what, const json& spec, HttpClient& in_process, HttpClient& cluster, int rounds,
              const std::vector<pid_t>& pids_a, const std::vector<pid_t>& pids_b) {
  std::vector<double> a, b, ratio, cpu_a, cpu_b, cpu_ratio;
  std::vector<std::vector<double>> cpu_parts(pids_b.size());
  json bits_a, bits_b;
  bool equal = true;
  job_wall(in_process, spec, nullptr);  // warm-up (page cache, scene build)
  job_wall(cluster, spec, nullptr);
  const double load_before = load1();
  for (int r = 0; r < rounds; ++r) {
    double ta = 0, tb = 0, ca = 0, cb = 0;
    auto side_a = [&] {
      const double c0 = cpu_seconds(pids_a);
      ta = job_wall(in_process, spec, &bits_a);
      ca = cpu_seconds(pids_a) - c0;
    };
    auto side_b = [&] {
      std::vector<double> c0;
      for (pid_t p : pids_b) c0.push_back(cpu_seconds(p));
      tb = job_wall(cluster, spec, &bits_b);
      for (size_t i = 0; i < pids_b.size(); ++i) {
        const double c = cpu_seconds(pids_b[i]) - c0[i];
        cpu_parts[i].push_back(c);
        cb += c;
      }
    };
    if (r % 2 == 0) {
      side_a();
      side_b();
    } else {
      side_b();
      side_a();
    }
    cpu_a.push_back(ca);
    cpu_b.push_back(cb);
    cpu_ratio.push_back(cb / ca);
    equal = equal && bits_a == bits_b;
    a.push_back(ta);
    b.push_back(tb);
    ratio.push_back(tb / ta);
  }
  std::vector<double> sorted = ratio;
  std::sort(sorted.begin(), sorted.end());
  auto q = [&](double f) { return sorted[static_cast<size_t>(f * static_cast<double>(sorted.size() - 1) + 0.5)]; };
  std::fflush(stdout);
  fmt::print("{:<34} in-process 2 threads {:7.3f} s   redis + 1 worker x 2 threads {:7.3f} s (medians)\n", what,
             median(a), median(b));
  fmt::print("{:<34} redis/in-process over {} pairs: median {:.3f}  [min {:.3f}, q1 {:.3f}, q3 {:.3f}, max {:.3f}]"
             "   bits {}   load {:.1f} -> {:.1f}\n",
             "", rounds, median(ratio), sorted.front(), q(0.25), q(0.75), sorted.back(), equal ? "equal" : "DIFFER",
             load_before, load1());
  std::sort(cpu_ratio.begin(), cpu_ratio.end());
  std::string parts;
  for (const auto& v : cpu_parts) parts += fmt::format("{}{:.3f}", parts.empty() ? "" : " + ", median(v));
  fmt::print("{:<34} CPU seconds per job (medians): in-process {:.3f}, cluster {:.3f} (server + worker + redis: {}); "
             "ratio median {:.3f} [q1 {:.3f}, q3 {:.3f}]\n",
             "", median(cpu_a), median(cpu_b), parts, median(cpu_ratio),
             cpu_ratio[static_cast<size_t>(0.25 * static_cast<double>(cpu_ratio.size() - 1) + 0.5)],
             cpu_ratio[static_cast<size_t>(0.75 * static_cast<double>(cpu_ratio.size() - 1) + 0.5)]);
}

// Drives a RedisExecutor with passes of `blocks_per_pass` one-sample blocks.
void ceiling(const std::string& url, size_t max_entry_blocks, size_t passes, size_t blocks_per_pass) {
  cluster::RedisExecutorConfig cfg;
  cfg.url = cluster::parse_redis_url(url);
  cfg.max_entry_blocks = max_entry_blocks;
  std::mutex mu;
  std::condition_variable cv;
  size_t done = 0;
  bool finished = false;
  auto make_pass = [&](uint64_t pass) {
    PassWork w;
    w.pass = pass;
    for (size_t i = 0; i < blocks_per_pass; ++i) w.blocks.push_back(Block{i, pass * blocks_per_pass + i, 1, 0});
    w.groups = result_groups(w.blocks, 1);  // every block's result travels alone: the worst case
    return w;
  };
  ExecutorCallbacks cb;
  cb.pass_done = [&](const std::string&, const PassWork& d, std::vector<BlockResult>&& r, double) {
    std::lock_guard lock(mu);
    done += r.size();
    if (d.pass + 1 >= passes) {
      finished = true;
      cv.notify_all();
      return PassWork{};
    }
    return make_pass(d.pass + 1);
  };
  cb.failed = [&](const std::string&, const std::string& e) {
    fmt::print("ceiling: job failed: {}\n", e);
    std::lock_guard lock(mu);
    finished = true;
    cv.notify_all();
  };
  cluster::RedisExecutor ex(cfg, cb);
  std::this_thread::sleep_for(1500ms);  // the worker registry is read once a second
  ExecutorJob job;
  job.id = fmt::format("ceiling{}", max_entry_blocks);
  job.spec_json = json{{"kind", "integrate"},
                       {"integrand", {{"builtin", "unit_disk"}}},
                       {"domain", {{"type", "box"}, {"lower", {-1, -1}}, {"upper", {1, 1}}}},
                       {"seed", 1},
                       {"stop", {{"max_samples", 1000000}}}}
                      .dump();
  job.epoch = 1;
  const auto t0 = std::chrono::steady_clock::now();
  ex.add(job, make_pass(0));
  std::unique_lock lock(mu);
  cv.wait_for(lock, 300s, [&] { return finished; });
  const double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  lock.unlock();
  ex.stop();
  fmt::print("coordinator ceiling, <= {:4} blocks/entry: {} passes x {} blocks in {:.2f} s = {:8.0f} blocks/s\n",
             max_entry_blocks, passes, blocks_per_pass, secs, static_cast<double>(done) / secs);
}

}  // namespace

int main(int argc, char** argv) {
  const int rounds = argc > 1 ? std::atoi(argv[1]) : 9;
  // "reclaim": part 3 alone; "preemption": part 4 alone; "lighting" / "colour" / "integration" / "heavy": that overhead alone.
  const std::string only = argc > 2 ? argv[2] : "";
  TempDir tmp;
  const fs::path sock = tmp.path / "r.sock";
  const pid_t redis = spawn_logged({"redis-server", "--port", "0", "--unixsocket", sock.string(), "--save", "", "--appendonly",
                             "no", "--maxmemory-policy", "noeviction", "--dir", tmp.path.string()},
                            tmp.path / "redis.log");
  std::this_thread::sleep_for(500ms);
  const std::string url = "unix://" + sock.string();
  int rc = 0;
  std::vector<pid_t> pids;
  try {
    const bool one_overhead = only == "lighting" || only == "colour" || only == "integration" || only == "heavy";
    if (only.empty() || one_overhead) {
    // 1. Overhead at equal cores.
    ServerProcess in_process(tmp.path / "a", {"--checkpoint-interval", "0.5"});
    ServerProcess cluster(tmp.path / "b", {"--redis", url, "--checkpoint-interval", "0.5"});
    pids.push_back(worker(url, "bench", 2, tmp.path));
    std::this_thread::sleep_for(1500ms);
    HttpClient ca = in_process.client(), cb = cluster.client();
    const std::vector<pid_t> pids_a = {in_process.pid()}, pids_b = {cluster.pid(), pids.back(), redis};
    if (only.empty() || only == "integration") {
      overhead("integration (unit disk, 4e8 samples)", disk_spec(400'000'000, 1), ca, cb, rounds, pids_a, pids_b);
    }
    if (only.empty() || only == "heavy") {
      // The same result size per block with ~20x the compute per block: the overhead is
      // per result, so it shrinks with the work per block.
      const json heavy = {{"kind", "integrate"},
                          {"integrand",
                           {{"expression",
                             "exp(-(x0*x0+x1*x1+x2*x2+x3*x3+x4*x4+x5*x5)) * cos(x0*x1 + x2*x3 + x4*x5) * "
                             "(1 + sin(x0+x1+x2+x3+x4+x5))"}}},
                          {"domain", {{"type", "box"}, {"lower", json::array({0, 0, 0, 0, 0, 0})},
                                      {"upper", json::array({1, 1, 1, 1, 1, 1})}}},
                          {"seed", 1},
                          {"stop", {{"max_samples", 100'000'000}}}};
      overhead("integration (6-D expression, 1e8 samples)", heavy, ca, cb, rounds, pids_a, pids_b);
    }
    std::ifstream in(std::string(TALLY_SOURCE_DIR) + "/examples/lecture_lighting_image.json");
    json image = json::parse(in);
    image["stop"] = {{"max_samples", 256}};
    image["query"].erase("adaptive");
    if (only.empty() || only == "lighting") {
      overhead("lighting image (128x96, 256 spp)", image, ca, cb, rounds, pids_a, pids_b);
    }
    if (only.empty() || only == "colour") {
      // The same scene in colour: a pixel's R, G and B tallies differ, so the wire
      // format's repeat code (a tally equal to the one before it) saves only black pixels.
      json colour = image;
      colour["scene"]["materials"]["white"]["albedo"] = json::array({0.8, 0.5, 0.3});
      colour["scene"]["materials"]["grey"]["albedo"] = json::array({0.2, 0.4, 0.3});
      colour["scene"]["materials"]["lamp"]["radiance"] = json::array({5, 4, 3});
      overhead("lighting image in colour (128x96, 256 spp)", colour, ca, cb, rounds, pids_a, pids_b);
    }
    in_process.terminate();
    cluster.terminate();
    reap(pids.back());
    pids.pop_back();
    }
    if (only.empty()) {
    // 2. Coordinator ceiling (its own Redis database; one worker process, 2 threads).
    const std::string url1 = url + "?db=1";
    pids.push_back(worker(url1, "ceiling", 2, tmp.path));
    ceiling(url1, 1, 10, 2000);
    ceiling(url1, 4096, 10, 20000);
    reap(pids.back());
    pids.pop_back();
    }
    if (one_overhead) {
      for (pid_t p : pids) reap(p);
      reap(redis);
      return 0;
    }

    if (only.empty() || only == "preemption") {
      // 4. Preemption latency through Redis: one 2-thread worker, --max-running 1; a
      // priority-5 job submitted right after a pass boundary of the running priority -5
      // image job (the worst moment: a whole pass to wait). Printed: its start after the
      // submit against the low job's pass in flight (from that job's own trace).
      const std::string url3 = url + "?db=3";
      ServerProcess farm(tmp.path / "d", {"--redis", url3, "--max-running", "1", "--preempt-min-run", "0"});
      pids.push_back(worker(url3, "farm", 2, tmp.path));
      HttpClient cf = farm.client();
      std::ifstream lecture(std::string(TALLY_SOURCE_DIR) + "/examples/lecture_lighting_image.json");
      json low = json::parse(lecture);
      low["stop"] = {{"max_samples", 1'000'000}};
      low["query"].erase("adaptive");
      const std::string a = submit(cf, low, "?priority=-5");
      const auto samples_of = [&](const std::string& id) {
        return get_json(cf, "/v1/jobs/" + id).value("samples", uint64_t{0});
      };
      while (get_json(cf, "/v1/jobs/" + a).value("passes", 0) < 6) std::this_thread::sleep_for(2ms);
      const uint64_t before = samples_of(a);
      uint64_t at_submit = before;
      while ((at_submit = samples_of(a)) == before) std::this_thread::sleep_for(1ms);  // a boundary just passed
      const auto t0 = std::chrono::steady_clock::now();
      const std::string b = submit(cf, disk_spec(2'000'000, 32), "?priority=5");
      while (get_json(cf, "/v1/jobs/" + b).at("state") == "queued") std::this_thread::sleep_for(1ms);
      const double started_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
      wait_state(cf, b, "succeeded", 120);
      json sa;
      while ((sa = get_json(cf, "/v1/jobs/" + a)).value("samples", uint64_t{0}) <= at_submit ||
             sa.at("state") != "running") {
        std::this_thread::sleep_for(5ms);
      }
      double pass_ms = -1;
      const json trace = sa.value("trace", json::array());
      for (size_t i = 1; i < trace.size(); ++i) {
        if (trace[i][1].get<uint64_t>() > at_submit) {
          pass_ms = 1e3 * (trace[i][0].get<double>() - trace[i - 1][0].get<double>());
          break;
        }
      }
      cf.request("DELETE", "/v1/jobs/" + a);
      fmt::print("preemption through Redis (--max-running 1, one 2-thread worker, lecture image at priority -5): a "
                 "priority-5 job submitted just after a pass boundary started {:.0f} ms later; the low job's pass in "
                 "flight took {:.0f} ms (latency / pass = {:.2f}; beyond the pass: {:.0f} ms)\n",
                 started_ms, pass_ms, pass_ms > 0 ? started_ms / pass_ms : -1.0, started_ms - pass_ms);
      farm.terminate();
      reap(pids.back());
      pids.pop_back();
      if (only == "preemption") {
        for (pid_t p : pids) reap(p);
        reap(redis);
        return 0;
      }
    }

    // 3. Reclaim latency after kill -9, lease 1 s.
    const std::string url2 = url + "?db=2";
    ServerProcess reclaim(tmp.path / "c", {"--redis", url2, "--lease", "1"});
    pid_t victim = worker(url2, "victim", 1, tmp.path);
    pids.push_back(worker(url2, "survivor", 1, tmp.path));
    std::this_thread::sleep_for(1500ms);
    HttpClient cc = reclaim.client();
    const std::string id = submit(cc, disk_spec(2'000'000'000ULL, 3));
    cluster::RedisConn rconn(cluster::parse_redis_url(url2));
    // Under way (entries of ~20 ms), then freeze the victim while it holds an entry and
    // kill it: the entry is certainly held at the kill.
    while (get_json(cc, "/v1/jobs/" + id).at("samples").get<uint64_t>() < 50'000'000) std::this_thread::sleep_for(20ms);
    std::string stream, entry;
    for (int i = 0; i < 2000 && entry.empty(); ++i) {
      ::kill(victim, SIGSTOP);
      for (const auto& s : rconn.cmd({"SMEMBERS", "tally:active"}).elems) {
        try {
          for (const auto& e : rconn.cmd({"XPENDING", s.str, "w", "-", "+", "100"}).elems) {
            if (e.elems.size() >= 2 && e.elems[1].str.rfind("victim/", 0) == 0) {
              stream = s.str;
              entry = e.elems[0].str;
            }
          }
        } catch (const std::exception&) {
        }
      }
      if (entry.empty()) {
        ::kill(victim, SIGCONT);
        std::this_thread::sleep_for(3ms);
      }
    }
    if (entry.empty()) throw std::runtime_error("the victim never held an entry");
    reap(victim);
    const auto t0 = std::chrono::steady_clock::now();
    double latency = -1;
    while (std::chrono::steady_clock::now() - t0 < 30s) {
      bool gone = false;
      cluster::RValue p;
      try {
        p = rconn.cmd({"XPENDING", stream, "w", entry, entry, "1"});
      } catch (const cluster::RedisReplyError&) {
        gone = true;  // the pass was merged: the entry was reclaimed and computed (an upper bound)
      }
      if (gone || p.elems.empty() || p.elems[0].elems[1].str.rfind("victim/", 0) != 0) {
        latency = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        break;
      }
      std::this_thread::sleep_for(2ms);
    }
    cc.request("DELETE", "/v1/jobs/" + id);
    const json r = get_json(cc, "/v1/workers").at("results");
    fmt::print("reclaim after kill -9 (lease 1.0 s): {:.3f} s (goal <= 2.0 s); results first {} duplicates {} -> "
               "duplicate ratio {:.5f}\n",
               latency, r.at("first").get<uint64_t>(), r.at("duplicates_equal").get<uint64_t>(),
               static_cast<double>(r.at("duplicates_equal").get<uint64_t>()) /
                   std::max<double>(1.0, static_cast<double>(r.at("first").get<uint64_t>())));
    reclaim.terminate();
  } catch (const std::exception& e) {
    fmt::print(stderr, "cluster_bench: {}\n", e.what());
    rc = 1;
  }
  for (pid_t p : pids) reap(p);
  reap(redis);
  return rc;
}
