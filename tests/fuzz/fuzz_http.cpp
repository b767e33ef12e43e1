// libFuzzer: the HTTP request path, raw bytes -> response bytes, through the same
// parser, limits and framing rules as a connection (respond_to_bytes) and the real
// request handler and routes. Oracles: every answer is a well-formed HTTP/1.1
// response, never a 500, and at most one answer per request the bytes could hold.
// Jobs are compiled (the real compilers) but never run: the compiler throws after
// checking the spec, so no worker thread makes runs differ.
#include <memory>
#include <string>

#include "common/jobs/job_factory.hpp"
#include "common/protocol/spec_reader.hpp"
#include "fuzz_support.hpp"
#include "server/http/http_server.hpp"
#include "server/jobs/job_manager.hpp"
#include "server/jobs/job_store.hpp"
#include "server/api/metrics.hpp"
#include "server/api/request_handler.hpp"

namespace {

struct World {
  World() : store(tally::make_memory_store()) {
    tally::ManagerConfig mc;
    mc.workers = 1;
    mc.limits.max_pixels = 64 * 64;
    mc.limits.max_quadrature_points = 1 << 12;
    manager = std::make_unique<tally::JobManager>(
        mc, *store, [](const nlohmann::json& spec, const tally::JobLimits& limits) -> std::unique_ptr<tally::JobDefinition> {
          tally::compile_job(spec, limits);
          throw tally::SpecError("", "fuzzing: jobs are compiled, not run");
        });
    manager->recover();
    tally::HandlerConfig hc;
    hc.pilot_seconds = 0.001;
    handler = std::make_unique<tally::RequestHandler>(*manager, metrics, hc);
    http.max_body_bytes = 1 << 16;
    http.max_header_bytes = 4 << 10;
  }
  std::unique_ptr<tally::JobStore> store;
  tally::Metrics metrics;
  std::unique_ptr<tally::JobManager> manager;
  std::unique_ptr<tally::RequestHandler> handler;
  tally::HttpServerConfig http;
};

size_t count(const std::string& hay, const std::string& needle) {
  size_t n = 0;
  for (size_t p = hay.find(needle); p != std::string::npos; p = hay.find(needle, p + 1)) ++n;
  return n;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static World* w = new World;  // lives for the whole run (threads of the manager)
  const std::string raw(reinterpret_cast<const char*>(data), size);
  const std::string out = tally::respond_to_bytes(raw, w->http, *w->handler);
  if (!raw.empty() && out.rfind("HTTP/1.", 0) != 0) tally::fuzz::fail("no status line", out.substr(0, 200), raw);
  if (out.find(" 500 ") != std::string::npos) tally::fuzz::fail("500", out.substr(0, 600), raw);
  // Each answer ends one request, and a request needs at least "X / HTTP/1.1\r\n\r\n".
  const size_t answers = count(out, "\r\nServer: tally-server") + count(out, "HTTP/1.1 ");
  if (answers / 2 > raw.size() / 16 + 1) tally::fuzz::fail("more answers than requests", out.substr(0, 600), raw);
  return 0;
}
