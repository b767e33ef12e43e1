// tally-server: the HTTP/JSON job server. See docs/api.md.
#include <CLI/CLI.hpp>
#include <fmt/format.h>

#include <malloc.h>

#include <csignal>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <future>
#include <memory>
#include <vector>

#include "common/protocol/job_kinds.hpp"
#include "server/assets/asset_retention.hpp"
#include "server/assets/asset_store.hpp"
#include "server/auth/access_control.hpp"
#include "server/auth/auth_file.hpp"
#include "server/auth/token.hpp"
#include "server/cluster/cluster_http.hpp"
#include "server/cluster/redis_executor.hpp"
#include "server/cluster/result_key.hpp"
#include "common/log/log.hpp"
#include "server/executor/cpu_quota.hpp"
#include "server/http/fd_limit.hpp"
#include "server/http/http_server.hpp"
#include "server/jobs/job_manager.hpp"
#include "server/host/memory_budget.hpp"
#include "server/cli/job_limit_flags.hpp"
#include "server/jobs/job_store.hpp"
#include "server/http/listen_address.hpp"
#include "server/api/metrics.hpp"
#include "server/http/problem.hpp"
#include "server/api/request_handler.hpp"

#if __has_include("common/image/image_io.hpp")
#include "common/image/image_io.hpp"
#define TALLY_HAVE_IMAGE_IO 1
#endif

int main(int argc, char** argv) {
  using namespace tally;
  // Per pass the server allocates and frees buffers of 0.1-10 MB (a cluster entry's
  // results and their decoded tallies, state copies for checkpoints, encoded
  // checkpoints). With glibc's defaults each came from a fresh mmap or a trimmed arena
  // and was page-faulted in again: ~4,000-7,000 faults per 0.8 s image job, which the
  // settings below take to ~0 (and the server's CPU per job from ~0.27 to ~0.18 s in
  // cluster mode, ~1.38 to ~1.29 s in process; docs/performance.md, 2026-12-02 evening).
  // States of 32 MB and more are still mmapped and returned at once; at most 64 MB of
  // free memory stays at an arena's top.
  mallopt(M_MMAP_THRESHOLD, 32 << 20);
  mallopt(M_TRIM_THRESHOLD, 64 << 20);
  CLI::App app{"tally-server: Monte Carlo estimation over HTTP/JSON"};
  std::string listen = "127.0.0.1:8080";
  std::string data_dir = "./var";
  std::string port_file;
  unsigned workers = 0;
  HttpServerConfig http;
  ManagerConfig mc;
  HandlerConfig hc;
  app.add_option("--listen", listen, "address:port to listen on (port 0: any free port)")->capture_default_str();
  app.add_option("--workers", workers, "worker threads (default: usable CPUs, honouring a cgroup CPU quota)");
  app.add_option("--data-dir", data_dir, "directory of the job database")->capture_default_str();
  app.add_option("--asset-dir", mc.limits.asset_dir, "directory scenes may load OBJ files from");
  uint64_t max_asset_bytes = uint64_t{1} << 30;
  double asset_retention_days = 30;
  app.add_option("--max-asset-bytes", max_asset_bytes, "largest asset PUT /v1/assets/... accepts, in bytes")
      ->capture_default_str();
  app.add_option("--asset-retention-days", asset_retention_days,
                 "stored assets no job names are removed once their last upload is this old (checked at start and "
                 "hourly; negative: never)")
      ->capture_default_str();
  app.add_option("--port-file", port_file, "write the bound port to this file once ready (jobs recovered)");
  app.add_option("--io-threads", http.io_threads, "threads serving connections")->capture_default_str();
  app.add_option("--max-body", http.max_body_bytes, "request body limit in bytes")->capture_default_str();
  app.add_option("--max-header", http.max_header_bytes, "request header limit in bytes")->capture_default_str();
  app.add_option("--idle-timeout", http.idle_timeout_s, "seconds a connection may wait for a request")->capture_default_str();
  app.add_option("--read-timeout", http.read_timeout_s, "seconds to receive a whole request once it started")
      ->capture_default_str();
  app.add_option("--write-timeout", http.write_timeout_s, "seconds to send a response (per event-stream chunk)")
      ->capture_default_str();
  app.add_option("--heartbeat", http.heartbeat_s, "seconds between keep-alive comments on idle event streams")
      ->capture_default_str();
  app.add_option("--max-connections", http.max_connections, "open connections")->capture_default_str();
  app.add_option("--max-json-depth", hc.max_json_depth, "nesting depth of request JSON")->capture_default_str();
  app.add_option("--max-running", mc.max_running, "jobs sharing the workers at once")->capture_default_str();
  app.add_option("--max-queued", mc.max_queued, "jobs waiting for a running slot (then 503)")->capture_default_str();
  app.add_option("--preempt-min-run", mc.preempt_min_run_s,
                 "seconds a job runs (since it started or resumed) before a waiting job of higher priority, or "
                 "of an owner below its fair share, may pause it at a pass boundary; negative: never preempt")
      ->capture_default_str();
  add_job_limit_flags(app, mc.limits);
  app.add_option("--checkpoint-interval", mc.checkpoint_interval_s, "least seconds between a job's checkpoints")
      ->capture_default_str();
  std::string checkpoint_copy = "16MiB";
  app.add_option("--checkpoint-copy-bytes", checkpoint_copy,
                 "a job state whose checkpoint is at most this size is copied at a pass boundary; a larger one "
                 "(an image's) streams from the live state, and its passes merge group by group as they come")
      ->capture_default_str();
  std::string memory_budget = "auto", finished_cache = "256MiB", retain_max_age = "0", retain_max_bytes = "0";
  app.add_option("--memory-budget", memory_budget,
                 "memory for jobs' state, e.g. 4GiB; a job needing more is refused (422), others wait to start; "
                 "auto: half of the machine's or cgroup's memory; 0: no budget")
      ->capture_default_str();
  app.add_option("--finished-cache", finished_cache, "finished jobs' states kept in memory for their images")
      ->capture_default_str();
  app.add_option("--retain-max-age", retain_max_age, "delete finished jobs older than this (e.g. 7d, 12h; 0: keep)")
      ->capture_default_str();
  app.add_option("--retain-max-jobs", mc.retain_max_jobs, "keep at most this many finished jobs (0: no limit)")
      ->capture_default_str();
  app.add_option("--retain-max-bytes", retain_max_bytes,
                 "keep finished jobs' stored rows under this size, e.g. 20GiB (0: no limit)")
      ->capture_default_str();
  app.add_option("--retention-interval", mc.retention_interval_s, "seconds between retention sweeps")
      ->capture_default_str();
  app.add_option("--event-buffer", mc.event_buffer, "events kept per job for Last-Event-ID resume")->capture_default_str();
  app.add_option("--pilot-seconds", hc.pilot_seconds, "length of the validate pilot run")->capture_default_str();
  app.add_option("--pilot-threads", http.slow_threads, "threads running validate pilots (their own pool)")
      ->capture_default_str();
  app.add_option("--max-pilot-requests", http.max_slow_requests,
                 "validate requests running or waiting at once (then 503 + Retry-After)")
      ->capture_default_str();
  std::string log_level = "info", log_format = "text";
  app.add_option("--log-level", log_level, "debug, info, warn, error or off")
      ->check(CLI::IsMember({"debug", "info", "warn", "error", "off"}))
      ->capture_default_str();
  app.add_option("--log-format", log_format, "text or json (one object per line)")
      ->check(CLI::IsMember({"text", "json"}))
      ->capture_default_str();
  std::string auth_file;
  bool insecure_no_auth = false;
  std::vector<std::string> allowed_hosts;
  app.add_option("--auth-file", auth_file, "principals and token hashes (JSON, docs/security.md); SIGHUP reloads it");
  app.add_flag("--insecure-no-auth", insecure_no_auth, "listen off loopback without --auth-file (anyone may do anything)");
  app.add_option("--allowed-host", allowed_hosts, "extra Host header value accepted without --auth-file (repeatable)");
  app.add_option("--tls-cert", http.tls_cert, "PEM certificate chain: serve HTTPS (needs --tls-key)");
  app.add_option("--tls-key", http.tls_key, "PEM private key of --tls-cert");

  // tally-server token new NAME --role user: a fresh token, shown once, and its entry.
  CLI::App* token_cmd = app.add_subcommand("token", "manage bearer tokens");
  CLI::App* token_new = token_cmd->add_subcommand("new", "print a fresh token and the auth-file entry to add");
  std::string token_name, token_role = "user";
  token_new->add_option("name", token_name, "principal name")->required();
  token_new->add_option("--role", token_role, "admin, user, reader or metrics")->capture_default_str();
  token_cmd->require_subcommand(1);

  std::string redis_url;
  double lease_s = 30.0;
  unsigned max_deliveries = 3;
  app.add_option("--redis", redis_url,
                 "cluster mode: blocks are computed by tally-worker processes through this Redis "
                 "(redis://[[user]:password@]host:port[/db] or unix:///path); the server computes nothing itself");
  app.add_option("--lease", lease_s, "cluster mode: seconds before a silent worker's block is reclaimed")
      ->capture_default_str();
  app.add_option("--max-deliveries", max_deliveries,
                 "cluster mode: failed deliveries of one block that fail its job")->capture_default_str();
  std::string result_key_file;
  app.add_option("--result-key-file", result_key_file,
                 "cluster mode: the shared secret (>= 32 bytes) tally-workers hold too; results and specs in Redis are "
                 "signed with it (HMAC-SHA-256), so one who can write to Redis without it cannot change them");
  CLI11_PARSE(app, argc, argv);
  log::configure(*log::parse_level(log_level), *log::parse_format(log_format));

  if (token_new->parsed()) {
    PrincipalEntry e;
    e.name = token_name;
    const auto role = parse_role(token_role);
    if (!role) {
      fmt::print(stderr, "tally-server: --role must be admin, user, reader or metrics, got \"{}\"\n", token_role);
      return 2;
    }
    e.role = *role;
    const std::string token = generate_token();
    e.token_sha256 = token_sha256_hex(token);
    try {
      parse_auth_file(nlohmann::json{{"principals", {principal_entry_json(e)}}});  // the name is valid
    } catch (const std::exception& ex) {
      fmt::print(stderr, "tally-server: {}\n", ex.what());
      return 2;
    }
    fmt::print(stderr, "The token is shown once; only its hash goes into the auth file. Add the entry below to\n"
                       "\"principals\" and send the server SIGHUP.\n");
    fmt::print("{}\n{}\n", token, principal_entry_json(e).dump());
    return 0;
  }

  const auto addr = parse_listen_address(listen);
  if (!addr) {
    log::error("--listen must be host:port, got \"{}\"", listen);
    return 2;
  }
  // Descriptors: raise the soft limit to the hard one, and keep --max-connections
  // below it so the connection limit (a clean 503) is reached before EMFILE.
  const size_t fd_limit = raise_fd_soft_limit();
  const size_t max_conn = connections_for_fd_limit(http.max_connections, fd_limit);
  if (max_conn < http.max_connections) {
    fmt::print(stderr, "tally-server: --max-connections {} lowered to {} (descriptor limit {})\n",
               http.max_connections, max_conn, fd_limit);
    http.max_connections = max_conn;
  }
  http.address = addr->host;
  http.port = addr->port;
  if (http.tls_cert.empty() != http.tls_key.empty()) {
    fmt::print(stderr, "tally-server: --tls-cert and --tls-key go together\n");
    return 2;
  }
  const bool loopback = is_loopback_address(http.address);
  if (!loopback && auth_file.empty() && !insecure_no_auth) {
    fmt::print(stderr,
               "tally-server: refusing to listen on {} without access control: anyone who reaches the port could\n"
               "run, read and cancel every job. Give --auth-file (docs/security.md), or --insecure-no-auth if\n"
               "something in front of the server already authenticates every caller.\n",
               http.address);
    return 2;
  }
  std::unique_ptr<AccessControl> access;
  if (!auth_file.empty()) {
    try {
      access = std::make_unique<AccessControl>(load_auth_file(auth_file));
    } catch (const std::exception& e) {
      fmt::print(stderr, "tally-server: {}\n", e.what());
      return 2;
    }
  }
  hc.access.access = access.get();
  hc.access.metrics_open = loopback;
  hc.access.check_host = !access;  // without tokens, only names of this machine (DNS rebinding)
  for (auto h : allowed_hosts) {
    for (char& c : h) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    hc.access.allowed_hosts.push_back(h);
  }
  hc.access.tls = !http.tls_cert.empty();
  hc.access.insecure_no_auth = !access && !loopback;
  if (hc.access.insecure_no_auth) {
    fmt::print(stderr,
               "tally-server: WARNING: INSECURE: listening on {} with NO ACCESS CONTROL (--insecure-no-auth).\n"
               "tally-server: WARNING: anyone who reaches this port may run, read and cancel every job.\n",
               http.address);
  }
  mc.workers = workers > 0 ? workers : default_worker_count();
  {
    const auto budget = memory_budget == "auto" ? std::optional<uint64_t>(default_memory_budget())
                                                : parse_byte_size(memory_budget);
    const auto cache = parse_byte_size(finished_cache);
    const auto age = parse_duration_s(retain_max_age);
    const auto bytes = parse_byte_size(retain_max_bytes);
    if (!budget || !cache || !age || !bytes) {
      fmt::print(stderr, "tally-server: {} is not a {}\n",
                 !budget ? "--memory-budget " + memory_budget
                 : !cache ? "--finished-cache " + finished_cache
                 : !age   ? "--retain-max-age " + retain_max_age
                          : "--retain-max-bytes " + retain_max_bytes,
                 !age && budget && cache ? "duration (90s, 15m, 12h, 7d)" : "size (4GiB, 512MiB, bytes)");
      return 2;
    }
    const auto copy = parse_byte_size(checkpoint_copy);
    if (!copy) {
      fmt::print(stderr, "tally-server: --checkpoint-copy-bytes {} is not a size (16MiB, 512KiB, bytes)\n",
                 checkpoint_copy);
      return 2;
    }
    mc.checkpoint_copy_bytes = *copy;
    mc.memory_budget = *budget;
    mc.finished_cache_bytes = *cache;
    mc.retain_max_age_s = *age;
    mc.retain_max_bytes = *bytes;
    if (mc.retention_interval_s <= 0) {
      fmt::print(stderr, "tally-server: --retention-interval must be positive\n");
      return 2;
    }
  }
#ifdef TALLY_HAVE_IMAGE_IO
  // The image module is loaded on the first image; without it the image routes answer 501.
  hc.images.exr_file = [](const ImageSource& source, const JobState& state, const nlohmann::json& meta,
                          const std::filesystem::path& path) {
    try {
      write_exr_file(source, state, meta, path);
    } catch (const ImageModuleUnavailable& e) {
      throw HttpError(501, e.what());
    }
  };
  hc.images.png = [](const ImageSnapshot& s) {
    try {
      return encode_png(s);
    } catch (const ImageModuleUnavailable& e) {
      throw HttpError(501, e.what());
    }
  };
#endif

  cluster::RedisExecutor* cluster_executor = nullptr;
  if (!redis_url.empty()) {
    cluster::RedisExecutorConfig rc;
    try {
      rc.url = cluster::parse_redis_url(redis_url);
    } catch (const std::exception& e) {
      log::error("--redis: {}", e.what());
      return 2;
    }
    if (!(lease_s >= 0.1) || max_deliveries < 1) {
      log::error("--lease must be >= 0.1 s and --max-deliveries >= 1");
      return 2;
    }
    // hiredis writes to its socket with write(2): a Redis that went away must be an
    // error the coordinator handles (jobs pause), not a SIGPIPE that ends the server.
    std::signal(SIGPIPE, SIG_IGN);
    // Refused credentials are a configuration error: exit with the reason instead of
    // serving with every job paused. An unreachable Redis is waited for (jobs pause).
    try {
      cluster::RedisConn probe(rc.url, std::chrono::milliseconds(3000));
    } catch (const cluster::RedisAuthError& e) {
      log::error("--redis: {}", e.what());
      return 2;
    } catch (const cluster::RedisIoError& e) {
      log::warn("--redis: {}; jobs wait until it is reachable", e.what());
    }
    rc.lease = std::chrono::milliseconds(static_cast<long long>(lease_s * 1000.0));
    rc.max_failures = max_deliveries;
    if (!result_key_file.empty()) {
      try {
        rc.result_key = cluster::load_result_key(result_key_file);
      } catch (const std::exception& e) {
        log::error("--result-key-file: {}", e.what());
        return 2;
      }
    }
    rc.asset_dir = mc.limits.asset_dir;
    rc.asset_store = (std::filesystem::path(data_dir) / "assets" / "sha256").string();
    mc.make_executor = [rc, &cluster_executor](ExecutorCallbacks cb) {
      auto ex = std::make_unique<cluster::RedisExecutor>(rc, std::move(cb));
      cluster_executor = ex.get();
      return std::unique_ptr<Executor>(std::move(ex));
    };
  }

  try {
    auto store = open_sqlite_store(data_dir);
    AssetStore assets(std::filesystem::path(data_dir) / "assets", max_asset_bytes);
    mc.limits.asset_store = assets.blob_dir().string();
    hc.assets = &assets;
    Metrics metrics;
    JobManager manager(mc, *store, [](const nlohmann::json& spec, const JobLimits& limits) {
      return compile_job(spec, limits);
    });
    if (cluster_executor) {
      hc.workers = [cluster_executor] { return cluster::workers_json(*cluster_executor); };
      hc.extra_metrics = [cluster_executor] { return cluster::cluster_metrics(*cluster_executor); };
    }
    RequestHandler handler(manager, metrics, hc);
    HttpServer server(http, handler, metrics);
    std::promise<int> signalled;
    server.on_signal([&signalled](int sig) { signalled.set_value(sig); });
    server.on_hangup([&access, &auth_file] {
      if (!access) return;
      try {
        const ReloadResult r = access->reload(load_auth_file(auth_file));
        log::info("SIGHUP: reloaded {}: {} principals, {} added, {} revoked", auth_file, r.principals, r.added,
                  r.revoked);
      } catch (const std::exception& e) {
        log::warn("SIGHUP: keeping the previous principals: {}", e.what());
      }
      std::fflush(stdout);
    });
    // Serve /livez, /readyz (503 until recovered) and /metrics while recovering; the
    // job routes answer 503 until then.
    handler.set_ready(false);
    const uint16_t port = server.start();
    // Recovered jobs are held to their owner's max_running_jobs, as new ones are.
    manager.recover([&access](const std::string& owner) {
      return access ? access->max_running_jobs_of(owner) : UINT64_MAX;
    });
    handler.set_ready(true);
    AssetRetention retention(assets, manager, asset_retention_days);
    if (!port_file.empty()) {  // written once ready
      const std::string tmp = port_file + ".tmp";
      std::ofstream(tmp) << port << "\n";
      std::filesystem::rename(tmp, port_file);
    }
    const std::string computing = cluster_executor
                                      ? fmt::format("cluster mode: workers through {}", cluster_executor->config().url.display())
                                      : fmt::format("{} workers", mc.workers);
    log::info("listening on {}://{}:{} ({}, data in {}, access control {})", http.tls_cert.empty() ? "http" : "https",
              http.address, port, computing, std::filesystem::absolute(data_dir).string(),
              access ? fmt::format("on, {} principals", access->principal_count()) : std::string("off"));
    log::info("memory budget for jobs' state {}; retention: max age {} s, max jobs {}, max bytes {} (0: none)",
              mc.memory_budget ? fmt::format("{:.0f} MiB", static_cast<double>(mc.memory_budget) / (1 << 20))
                               : std::string("none"),
              mc.retain_max_age_s, mc.retain_max_jobs, mc.retain_max_bytes);

    const int sig = signalled.get_future().get();
    log::info("signal {}: checkpointing jobs and shutting down", sig);
    server.stop_accepting();
    handler.set_ready(false);
    retention.stop();
    manager.shutdown();  // checkpoints unfinished jobs, ends every event stream
    server.stop(2.0);
    return 0;
  } catch (const std::exception& e) {
    log::error("{}", e.what());
    return 1;
  }
}
