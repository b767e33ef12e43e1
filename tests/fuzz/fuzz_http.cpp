// libFuzzer: the HTTP request path, raw bytes -> response bytes, through the same
// parser, limits and framing rules as a connection (respond_to_bytes) and the real
// request handler and routes. Oracles: every answer is a well-formed HTTP/1.1
// response, never a 500, and at most one answer per request the bytes could hold.
// Jobs are compiled (the real compilers) but never run: the compiler throws after
// checking the spec, so no worker thread makes runs differ.
#include <cstdlib>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "common/protocol/job_kinds.hpp"
#include "common/spec/spec_reader.hpp"
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

// The status codes of the answers in `out`, read one response after the other (status
// line, headers, Content-Length body): a body that echoes the client's bytes (a 415 quoting
// the Content-Type " 500 ...") is not mistaken for a status. Empty optional: `out` is not
// a sequence of well-formed responses.
std::optional<std::vector<int>> statuses(const std::string& out) {
  std::vector<int> codes;
  size_t p = 0;
  while (p < out.size()) {
    if (out.compare(p, 7, "HTTP/1.") != 0 || p + 12 > out.size() || out[p + 8] != ' ') return std::nullopt;
    int code = 0;
    for (size_t i = p + 9; i < p + 12; ++i) {
      if (out[i] < '0' || out[i] > '9') return std::nullopt;
      code = code * 10 + (out[i] - '0');
    }
    const size_t head_end = out.find("\r\n\r\n", p);
    if (head_end == std::string::npos) return std::nullopt;
    size_t length = 0;
    const std::string head = out.substr(p, head_end - p);
    const size_t cl = head.find("\r\nContent-Length: ");
    if (cl != std::string::npos) length = std::strtoull(head.c_str() + cl + 18, nullptr, 10);
    codes.push_back(code);
    p = head_end + 4 + length;
  }
  if (p != out.size()) return std::nullopt;
  return codes;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static World* w = new World;  // lives for the whole run (threads of the manager)
  const std::string raw(reinterpret_cast<const char*>(data), size);
  const std::string out = tally::respond_to_bytes(raw, w->http, *w->handler);
  const auto codes = statuses(out);
  if (!codes) tally::fuzz::fail("not a sequence of HTTP/1.x responses", out.substr(0, 600), raw);
  if (!raw.empty() && codes->empty()) tally::fuzz::fail("no answer", "", raw);
  for (const int code : *codes) {
    if (code == 500) tally::fuzz::fail("500", out.substr(0, 600), raw);
  }
  // Each answer ends one request, and a request needs at least "X / HTTP/1.1\r\n\r\n".
  if (codes->size() > raw.size() / 16 + 1) tally::fuzz::fail("more answers than requests", out.substr(0, 600), raw);
  return 0;
}
