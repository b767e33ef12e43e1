// tally-server: the HTTP/JSON job server. See docs/api.md.
#include <CLI/CLI.hpp>
#include <fmt/format.h>

#include <csignal>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <future>

#include "common/jobs/job_factory.hpp"
#include "server/cluster/cluster_http.hpp"
#include "server/cluster/redis_executor.hpp"
#include "common/log/log.hpp"
#include "server/executor/cpu_quota.hpp"
#include "server/http/http_server.hpp"
#include "server/jobs/job_manager.hpp"
#include "server/jobs/job_store.hpp"
#include "server/http/listen_address.hpp"
#include "server/api/metrics.hpp"
#include "server/api/problem.hpp"
#include "server/api/request_handler.hpp"

#if __has_include("common/image/image_io.hpp")
#include "common/image/image_io.hpp"
#define TALLY_HAVE_IMAGE_IO 1
#endif

int main(int argc, char** argv) {
  using namespace tally;
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
  app.add_option("--port-file", port_file, "write the bound port to this file once listening");
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
  app.add_option("--max-dimensions", mc.limits.max_dimensions, "per-job cap: integration dimensions")->capture_default_str();
  app.add_option("--max-channels", mc.limits.max_channels, "per-job cap: channels")->capture_default_str();
  app.add_option("--max-samples", mc.limits.max_samples, "per-job cap: samples")->capture_default_str();
  app.add_option("--max-seconds", mc.limits.max_seconds, "per-job cap: compute seconds")->capture_default_str();
  app.add_option("--max-pixels", mc.limits.max_pixels, "per-job cap: image pixels")->capture_default_str();
  app.add_option("--checkpoint-interval", mc.checkpoint_interval_s, "least seconds between a job's checkpoints")
      ->capture_default_str();
  app.add_option("--event-buffer", mc.event_buffer, "events kept per job for Last-Event-ID resume")->capture_default_str();
  app.add_option("--pilot-seconds", hc.pilot_seconds, "length of the validate pilot run")->capture_default_str();
  std::string log_level = "info", log_format = "text";
  app.add_option("--log-level", log_level, "debug, info, warn, error or off")
      ->check(CLI::IsMember({"debug", "info", "warn", "error", "off"}))
      ->capture_default_str();
  app.add_option("--log-format", log_format, "text or json (one object per line)")
      ->check(CLI::IsMember({"text", "json"}))
      ->capture_default_str();
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
  CLI11_PARSE(app, argc, argv);
  log::configure(*log::parse_level(log_level), *log::parse_format(log_format));

  const auto addr = parse_listen_address(listen);
  if (!addr) {
    log::error("--listen must be host:port, got \"{}\"", listen);
    return 2;
  }
  http.address = addr->host;
  http.port = addr->port;
  mc.workers = workers > 0 ? workers : default_worker_count();
#ifdef TALLY_HAVE_IMAGE_IO
  // The image module is loaded on the first image; without it the image routes answer 501.
  hc.images.exr = [](const ImageSnapshot& s, const nlohmann::json& meta) {
    try {
      return encode_exr(s, meta);
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
    rc.lease = std::chrono::milliseconds(static_cast<long long>(lease_s * 1000.0));
    rc.max_failures = max_deliveries;
    rc.asset_dir = mc.limits.asset_dir;
    mc.make_executor = [rc, &cluster_executor](ExecutorCallbacks cb) {
      auto ex = std::make_unique<cluster::RedisExecutor>(rc, std::move(cb));
      cluster_executor = ex.get();
      return std::unique_ptr<Executor>(std::move(ex));
    };
  }

  try {
    auto store = open_sqlite_store(data_dir);
    Metrics metrics;
    JobManager manager(mc, *store, [](const nlohmann::json& spec, const JobLimits& limits) {
      return compile_job(spec, limits);
    });
    manager.recover();
    if (cluster_executor) {
      hc.workers = [cluster_executor] { return cluster::workers_json(*cluster_executor); };
      hc.extra_metrics = [cluster_executor] { return cluster::cluster_metrics(*cluster_executor); };
    }
    RequestHandler handler(manager, metrics, hc);
    HttpServer server(http, handler, metrics);
    std::promise<int> signalled;
    server.on_signal([&signalled](int sig) { signalled.set_value(sig); });
    const uint16_t port = server.start();
    if (!port_file.empty()) {
      const std::string tmp = port_file + ".tmp";
      std::ofstream(tmp) << port << "\n";
      std::filesystem::rename(tmp, port_file);
    }
    if (cluster_executor) {
      fmt::print("tally-server listening on http://{}:{} (cluster mode: workers through {}, data in {})\n",
                 http.address, port, cluster_executor->config().url.display(),
                 std::filesystem::absolute(data_dir).string());
    } else {
      fmt::print("tally-server listening on http://{}:{} ({} workers, data in {})\n", http.address, port, mc.workers,
                 std::filesystem::absolute(data_dir).string());
    }
    std::fflush(stdout);
    if (cluster_executor) {
      log::info("listening on {}:{} (cluster mode through {}, data in {})", http.address, port,
                cluster_executor->config().url.display(), std::filesystem::absolute(data_dir).string());
    } else {
      log::info("listening on {}:{} ({} workers, data in {})", http.address, port, mc.workers,
                std::filesystem::absolute(data_dir).string());
    }

    const int sig = signalled.get_future().get();
    log::info("signal {}: checkpointing jobs and shutting down", sig);
    server.stop_accepting();
    handler.set_ready(false);
    manager.shutdown();  // checkpoints unfinished jobs, ends every event stream
    server.stop(2.0);
    return 0;
  } catch (const std::exception& e) {
    log::error("{}", e.what());
    return 1;
  }
}
