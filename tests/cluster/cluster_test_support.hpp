#pragma once
// What the cluster tests share: a run of a spec in this process to compare bits with,
// a TestCluster (private Redis, tally-server --redis, workers), bounded waits and the
// image helpers.
#include <gtest/gtest.h>
#include <OpenImageIO/imageio.h>

#include <bit>
#include <chrono>
#include <fmt/format.h>
#include <fstream>
#include <memory>
#include <thread>

#include "cluster_process.hpp"
#include "common/engine/pass_loop.hpp"
#include "common/protocol/job_json.hpp"
#include "common/protocol/job_kinds.hpp"
#include "server_process.hpp"

namespace tally::e2e {

using nlohmann::json;
using namespace std::chrono_literals;
namespace fs = std::filesystem;

// The bits `GET /v1/jobs/{id}` reports, from a run of the spec in this process.
// `extend_to` > 0: then extended to that many samples, like POST .../extend.
inline json local_bits(const json& spec, uint64_t extend_to = 0, const JobLimits& limits = {}) {
  const auto def = compile_job(spec, limits);
  JobRunner runner(def->kernel(), def->stop_rule(), JobCaps{});
  run_local(runner, 2);
  if (extend_to > 0) {
    StopRule rule;
    rule.confidence = runner.rule().confidence;
    rule.min_samples = runner.rule().min_samples;
    rule.max_samples = extend_to;
    runner.extend(rule);
    run_local(runner, 2);
  }
  return tally_bits_json(runner.state());  // what the status document's "bits" shows
}

inline std::vector<std::string> cluster_flags(const RedisServer& redis, double lease_s = 30) {
  return {"--redis", redis.url(), "--lease", fmt::format("{}", lease_s), "--checkpoint-interval", "0"};
}

// One unlabelled sample of the server's /metrics (throws if it has none).
inline double metric(HttpClient& c, const std::string& name) {
  const std::string body = c.request("GET", "/metrics").body;
  const size_t at = body.find("\n" + name + " ");
  if (at == std::string::npos) throw std::runtime_error("no metric " + name);
  return std::stod(body.substr(at + name.size() + 2));
}

inline json metrics_counts(HttpClient& c) {
  const json w = get_json(c, "/v1/workers");
  return w.at("results");
}

// Waits (bounded) until `pred` holds.
template <class Pred>
void wait_until(Pred pred, double timeout_s, const std::string& what) {
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
  while (std::chrono::steady_clock::now() < deadline) {
    if (pred()) return;
    std::this_thread::sleep_for(20ms);
  }
  throw std::runtime_error("timed out waiting for " + what);
}

inline size_t live_workers(HttpClient& c) { return get_json(c, "/v1/workers").at("workers").size(); }

// One worker of a TestCluster (WorkerProcess's arguments after the URL).
struct WorkerSpec {
  std::string name;
  unsigned threads = 1;
  std::vector<std::string> extra = {};
  WorkerOptions options = {};
};

struct ClusterOptions {
  double lease_s = 30;
  std::vector<std::string> server_flags = {};  // after cluster_flags()
};

// The usual cluster of a test, in `dir`: a private Redis, tally-server --redis on it
// and the workers, every one of them listed in /v1/workers before the test goes on
// (bounded wait). Torn down in reverse: workers, client, server, Redis.
struct TestCluster {
  TestCluster(const fs::path& dir, const std::vector<WorkerSpec>& specs, ClusterOptions o = {})
      : redis(dir), server(dir / "data", server_flags(redis, std::move(o))), c(server.client()) {
    for (const WorkerSpec& w : specs) {
      workers.push_back(std::make_unique<WorkerProcess>(redis.url(), w.name, dir, w.threads, w.extra, w.options));
    }
    if (!workers.empty()) {
      wait_until([&] { return live_workers(c) == workers.size(); }, 20,
                 fmt::format("{} workers in /v1/workers", workers.size()));
    }
  }
  WorkerProcess& worker(size_t i) { return *workers.at(i); }

  RedisServer redis;
  ServerProcess server;
  HttpClient c;
  std::vector<std::unique_ptr<WorkerProcess>> workers;

 private:
  static std::vector<std::string> server_flags(const RedisServer& redis, ClusterOptions o) {
    std::vector<std::string> flags = cluster_flags(redis, o.lease_s);
    flags.insert(flags.end(), o.server_flags.begin(), o.server_flags.end());
    return flags;
  }
};

inline json lighting_image_spec(int spp) {
  std::ifstream in(std::string(TALLY_SOURCE_DIR) + "/examples/lecture_lighting_image.json");
  json spec = json::parse(in);
  spec["scene"]["camera"]["resolution"] = {64, 48};
  spec["stop"] = {{"max_samples", spp}};
  spec["query"].erase("adaptive");
  return spec;
}

inline std::vector<float> exr_pixels(HttpClient& c, const std::string& id, const fs::path& tmp) {
  const ClientResponse r = c.request("GET", "/v1/jobs/" + id + "/image.exr");
  if (r.status != 200) throw std::runtime_error("image.exr: " + std::to_string(r.status));
  const fs::path file = tmp / (id + ".exr");
  std::ofstream(file, std::ios::binary) << r.body;
  auto in = OIIO::ImageInput::open(file.string());
  if (!in) throw std::runtime_error("cannot open the EXR");
  const OIIO::ImageSpec& spec = in->spec();
  std::vector<float> out;
  for (const char* name : {"R", "G", "B"}) {
    const int ch = spec.channelindex(name);
    if (ch < 0) throw std::runtime_error(std::string("EXR has no channel ") + name);
    std::vector<float> plane(static_cast<size_t>(spec.width) * static_cast<size_t>(spec.height));
    in->read_image(0, 0, ch, ch + 1, OIIO::TypeDesc::FLOAT, plane.data());
    out.insert(out.end(), plane.begin(), plane.end());
  }
  return out;
}

// An image job's `bits` and EXR pixels from an in-process tally-server: what a cluster
// run of the same spec must equal.
struct ImageReference {
  json bits;
  std::vector<float> pixels;
};
inline ImageReference in_process_image(const fs::path& tmp, const json& spec) {
  ServerProcess ref(tmp / "ref");
  HttpClient c = ref.client();
  const std::string id = submit(c, spec);
  ImageReference out{wait_state(c, id, "succeeded").at("bits"), exr_pixels(c, id, tmp)};
  ref.terminate();
  return out;
}

}  // namespace tally::e2e
