// tally-worker's command line: flags -> WorkerConfig, a credential check, run_worker.
// See docs/cluster.md.
#include <CLI/CLI.hpp>
#include <fmt/format.h>
#include <signal.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <filesystem>
#include <thread>

#include "common/spec/pool_field.hpp"
#include "server/cluster/result_key.hpp"
#include "server/cluster/worker.hpp"
#include "server/cli/job_limit_flags.hpp"

namespace tally::cluster {

namespace {
std::atomic<bool> g_stop{false};
void on_signal(int) { g_stop = true; }
}  // namespace

int worker_main(int argc, char** argv,
                std::function<std::shared_ptr<const Kernel>(std::shared_ptr<const Kernel>)> wrap_kernel) {
  CLI::App app{"tally-worker: computes tally blocks taken from Redis (cluster mode)"};
  std::string url;
  WorkerConfig cfg;
  std::string cache_dir;
  app.add_option("--redis", url,
                 "redis://[[user]:password@]host:port[/db] or unix://[[user]:password@]/path/to.sock[?db=N]")
      ->required();
  app.add_option("--threads", cfg.threads, "compute threads (default: hardware threads)");
  app.add_option("--name", cfg.name, "unique worker name (default: host-pid)");
  app.add_option("--cache-dir", cache_dir, "asset cache (default: $TMPDIR/tally-worker-<name>)");
  app.add_option("--health-file", cfg.health_file, "file rewritten at every heartbeat (for liveness probes)");
  std::string key_file;
  app.add_option("--result-key-file", key_file,
                 "the cluster's shared secret (as tally-server's): results and specs in Redis are signed with it");
  app.add_option("--pool", cfg.pools,
                 "a worker pool this worker serves (repeatable): it takes jobs whose spec names one of its pools, "
                 "and jobs without a pool; without --pool, jobs without a pool only")
      ->check([](const std::string& name) {
        const std::string why = pool_name_problem(name);
        return why.empty() ? why : fmt::format("a pool name {}, got \"{}\"", why, name);
      });
  add_job_limit_flags(app, cfg.limits);
  app.add_flag("--verbose", cfg.verbose, "log every block");
  CLI11_PARSE(app, argc, argv);
  try {
    cfg.url = parse_redis_url(url);
  } catch (const std::exception& e) {
    fmt::print(stderr, "tally-worker: --redis: {}\n", e.what());
    return 2;
  }
  if (!key_file.empty()) {
    try {
      cfg.result_key = load_result_key(key_file);
    } catch (const std::exception& e) {
      fmt::print(stderr, "tally-worker: --result-key-file: {}\n", e.what());
      return 2;
    }
  }
  cfg.wrap_kernel = std::move(wrap_kernel);
  char host[256] = {};
  ::gethostname(host, sizeof host - 1);
  cfg.host = host;
  if (cfg.name.empty()) cfg.name = fmt::format("{}-{}", cfg.host, ::getpid());
  if (cfg.threads == 0) cfg.threads = std::max(1u, std::thread::hardware_concurrency());
  cfg.cache_dir = cache_dir.empty() ? std::filesystem::temp_directory_path() / ("tally-worker-" + cfg.name)
                                    : std::filesystem::path(cache_dir);
  struct sigaction sa {};
  sa.sa_handler = on_signal;
  ::sigaction(SIGTERM, &sa, nullptr);
  ::sigaction(SIGINT, &sa, nullptr);
  // A write to a connection Redis closed (restart) must be an error, not process death.
  ::signal(SIGPIPE, SIG_IGN);
  // Wrong credentials are a configuration error: say so and exit rather than retry
  // forever. A Redis that is merely not up yet (compose starts everything at once) is
  // waited for.
  try {
    RedisConn probe(cfg.url);
  } catch (const RedisAuthError& e) {
    fmt::print(stderr, "tally-worker {}: {}\n", cfg.name, e.what());
    return 2;
  } catch (const RedisIoError& e) {
    fmt::print("tally-worker {}: {}; waiting for redis\n", cfg.name, e.what());
  }
  std::sort(cfg.pools.begin(), cfg.pools.end());
  cfg.pools.erase(std::unique(cfg.pools.begin(), cfg.pools.end()), cfg.pools.end());
  fmt::print("tally-worker {} ({} threads{}) on {}\n", cfg.name, cfg.threads,
             cfg.pools.empty() ? std::string() : fmt::format(", pools {}", fmt::join(cfg.pools, ",")), cfg.url.display());
  std::fflush(stdout);
  const int rc = run_worker(cfg, g_stop);
  std::error_code ec;
  if (cache_dir.empty()) std::filesystem::remove_all(cfg.cache_dir, ec);
  return rc;
}

}  // namespace tally::cluster
