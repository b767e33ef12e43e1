#pragma once
// A JobManager + RequestHandler on an in-memory (or SQLite) store with the fake
// job kind, and bounded waiting.
#include <chrono>
#include <functional>
#include <memory>
#include <nlohmann/json.hpp>
#include <thread>

#include "common/protocol/job_kinds.hpp"
#include "fake_job.hpp"
#include "server/jobs/job_manager.hpp"
#include "server/jobs/job_store.hpp"
#include "server/api/metrics.hpp"
#include "server/api/request_handler.hpp"

namespace tally::test {

inline bool wait_until(const std::function<bool()>& pred, double seconds = 20.0) {
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
  while (std::chrono::steady_clock::now() < deadline) {
    if (pred()) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
  return pred();
}

// The fake kind (fake_job.hpp) for scheduling, the real kinds for sizes that matter.
inline std::unique_ptr<JobDefinition> compile_any(const nlohmann::json& spec, const JobLimits& limits) {
  if (spec.is_object() && spec.value("kind", "") == "fake") return compile_fake_job(spec, limits);
  return compile_job(spec, limits);
}

inline ManagerConfig test_manager_config(unsigned workers = 2) {
  ManagerConfig c;
  c.workers = workers;
  c.checkpoint_interval_s = 0;  // every pass
  return c;
}

struct Harness {
  // `compile`: the fake kind only, or compile_any for the real kinds too.
  explicit Harness(ManagerConfig mc = test_manager_config(), std::unique_ptr<JobStore> s = make_memory_store(),
                   HandlerConfig hc = {}, JobCompiler compile = compile_fake_job)
      : store(std::move(s)), manager(std::make_unique<JobManager>(mc, *store, std::move(compile))) {
    manager->recover();
    hc.pilot_seconds = 0.05;
    handler = std::make_unique<RequestHandler>(*manager, metrics, hc);
  }
  ~Harness() {
    handler.reset();
    if (manager) manager->shutdown();
  }

  HttpResponse call(std::string method, std::string target, std::string body = {},
                    std::string content_type = "application/json", HttpRequest::Headers extra = {}) {
    HttpRequest r;
    r.method = std::move(method);
    r.target = std::move(target);
    if (!content_type.empty()) r.headers.emplace_back("content-type", content_type);
    for (auto& h : extra) r.headers.push_back(h);
    r.body = std::move(body);
    return handler->handle(r);
  }
  nlohmann::json call_json(std::string method, std::string target, std::string body = {}) {
    return nlohmann::json::parse(call(std::move(method), std::move(target), std::move(body)).body);
  }
  std::string submit(const nlohmann::json& spec) {
    auto r = call("POST", "/v1/jobs", spec.dump());
    if (r.status != 202) throw std::runtime_error("submit: " + r.body);
    return nlohmann::json::parse(r.body).at("id").get<std::string>();
  }
  std::string state(const std::string& id) { return call_json("GET", "/v1/jobs/" + id).at("state"); }
  bool wait_state(const std::string& id, const std::string& s, double seconds = 30) {
    return wait_until([&] { return state(id) == s; }, seconds);
  }

  std::unique_ptr<JobStore> store;
  Metrics metrics;
  std::unique_ptr<JobManager> manager;
  std::unique_ptr<RequestHandler> handler;
};

}  // namespace tally::test
