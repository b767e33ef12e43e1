// Golden outputs of the example jobs (examples/*.json) run through the server's
// request handler with the real job kinds: the status document, the job-list
// entry, both event streams (full replay and a new watcher's snapshot), a tile and
// the PNG/EXR bytes. They are compared byte for byte with tests/golden/data/, so a
// restructuring that changes what a client reads fails here.
//
// Only fields that depend on the clock or on the random job id are masked (see
// kVolatile); every document is first checked to be nlohmann's canonical dump, so
// comparing the masked canonical text is comparing the bytes.
// TALLY_UPDATE_GOLDEN=1 rewrites the files instead of comparing; it refuses to write new
// result bits (channel 0's tally, the image bytes) under the results version the file
// was written with: a change that alters what a spec and seed compute must bump
// kResultsVersion (common/engine/results_version.hpp), or the result cache would
// answer submits with the older bits.
#include <gtest/gtest.h>

#include <fmt/format.h>

#include <chrono>
#include <cstdlib>
#include <fstream>
#include <regex>
#include <set>
#include <sstream>
#include <thread>

#include "common/engine/pass_loop.hpp"
#include "common/engine/results_version.hpp"
#include "common/protocol/job_kinds.hpp"
#include "common/protocol/job_json.hpp"
#include "server/jobs/job_manager.hpp"
#include "server/http/event_stream.hpp"
#include "server/jobs/job_store.hpp"
#include "server/api/metrics.hpp"
#include "tests/support/response_body.hpp"
#include "server/api/request_handler.hpp"

#if __has_include("common/image/image_io.hpp")
#include "common/image/image_io.hpp"
#include "support/requested_image_module.hpp"
#define TALLY_HAVE_IMAGE_IO 1
#endif

namespace tally::test {
namespace {

using nlohmann::json;

// Keys whose values depend on the clock (throughput, timings, time-based forecasts).
const std::set<std::string> kVolatile = {"compute_seconds", "samples_per_second", "eta_seconds",
                                         "seconds_remaining", "seconds",         "timing",
                                         "created_at",      "efficiency",         "seconds_per_sample"};

std::string read_file(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error("cannot read " + path);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

std::string replace_all(std::string s, const std::string& from, const std::string& to) {
  if (from.empty()) return s;
  for (size_t p = s.find(from); p != std::string::npos; p = s.find(from, p + to.size())) s.replace(p, from.size(), to);
  return s;
}

std::string dump(const json& j) { return j.dump(-1, ' ', false, json::error_handler_t::replace); }

void mask(json& j, const std::string& id) {
  if (j.is_object()) {
    for (auto it = j.begin(); it != j.end(); ++it) {
      if (kVolatile.count(it.key())) {
        it.value() = "<volatile>";
      } else if (it.key() == "trace" && it.value().is_array()) {
        for (json& p : it.value()) p[0] = "<time>";  // [time_s, samples, mean, std_error]
      } else {
        mask(it.value(), id);
      }
    }
  } else if (j.is_array()) {
    for (json& x : j) mask(x, id);
  } else if (j.is_string()) {
    // Summary lines of lighting points end in a measured efficiency 1/(σ²t).
    static const std::regex efficiency("efficiency 1/\\(σ²t\\) [^\\n]*");
    j = std::regex_replace(replace_all(j.get<std::string>(), id, "<id>"), efficiency, "efficiency <volatile>");
  }
}

// The masked canonical text of a JSON document, after checking that `text` is
// exactly its canonical dump (plus `suffix`).
std::string masked(const std::string& text, const std::string& id, const std::string& suffix = "") {
  json j = json::parse(text);
  EXPECT_EQ(dump(j) + suffix, text) << "not a canonical dump";
  mask(j, id);
  return dump(j);
}

std::string fnv1a64(const std::string& bytes) {
  uint64_t h = 1469598103934665603ULL;
  for (unsigned char c : bytes) {
    h ^= c;
    h *= 1099511628211ULL;
  }
  return fmt::format("{:016x}", h);
}

bool wait_until(const std::function<bool()>& pred, double seconds) {
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
  while (std::chrono::steady_clock::now() < deadline) {
    if (pred()) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  return pred();
}

struct Server {
  Server() {
    ManagerConfig mc;
    mc.workers = 2;
    mc.checkpoint_interval_s = 0;
    mc.event_buffer = 1'000'000;  // the whole stream stays replayable
    store = make_memory_store();
    manager = std::make_unique<JobManager>(mc, *store, [](const json& spec, const JobLimits& limits) {
      return compile_job(spec, limits);
    });
    manager->recover();
    HandlerConfig hc;
#ifdef TALLY_HAVE_IMAGE_IO
    hc.images.exr_file = [](const ImageSource& src, const JobState& state, const json& meta,
                            const std::filesystem::path& path) { write_exr_file(src, state, meta, path); };
    hc.images.png = [](const ImageSnapshot& s) { return encode_png(s); };
#endif
    handler = std::make_unique<RequestHandler>(*manager, metrics, hc);
  }
  ~Server() {
    handler.reset();
    manager->shutdown();
  }
  HttpResponse call(const std::string& method, const std::string& target, const std::string& body = {},
                    HttpRequest::Headers headers = {}) {
    HttpRequest r;
    r.method = method;
    r.target = target;
    r.headers = std::move(headers);
    if (!body.empty()) r.headers.emplace_back("content-type", "application/json");
    r.body = body;
    return handler->handle(r);
  }
  // The whole NDJSON stream of a job (it has finished, so the stream ends).
  std::vector<std::string> events(const std::string& id, HttpRequest::Headers headers) {
    headers.emplace_back("accept", "application/x-ndjson");
    HttpResponse r = call("GET", "/v1/jobs/" + id + "/events", {}, headers);
    EXPECT_EQ(r.status, 200);
    std::string text;
    for (int i = 0; i < 100000 && r.stream; ++i) {
      if (!r.stream->poll(text)) break;
    }
    std::vector<std::string> lines;
    std::istringstream in(text);
    for (std::string line; std::getline(in, line);) {
      json e = json::parse(line);
      // The line is {"id":..,"event":..,"data":<data verbatim>}: check and mask the data.
      const std::string data = dump(e.at("data"));
      EXPECT_NE(line.find(data), std::string::npos) << line;
      lines.push_back(fmt::format("{} {} {}", e.at("id").get<uint64_t>(), e.at("event").get<std::string>(),
                                  masked(data, id)));
    }
    return lines;
  }

  std::unique_ptr<JobStore> store;
  Metrics metrics;
  std::unique_ptr<JobManager> manager;
  std::unique_ptr<RequestHandler> handler;
};

// An example spec, with any time budget removed so that only samples and error
// targets decide when it stops (a loaded machine must not change the outputs).
// The unit disk's 1e-4 target needs ~1e8 samples: it stops at 1e6 here.
json example(const std::string& name) {
  json spec = json::parse(read_file(std::string(TALLY_SOURCE_DIR) + "/examples/" + name + ".json"));
  if (spec.contains("stop")) spec["stop"].erase("time_budget_s");
  if (name == "unit_disk_expression") spec["stop"] = {{"max_samples", 1000000}};
  return spec;
}

json run_example(const std::string& name) {
  Server s;
  const json spec = example(name);
  const HttpResponse post = s.call("POST", "/v1/jobs", dump(spec));
  EXPECT_EQ(post.status, 202) << post.body;
  const std::string id = json::parse(post.body).at("id");
  EXPECT_TRUE(wait_until(
      [&] { return json::parse(s.call("GET", "/v1/jobs/" + id).body).at("state") != "running"; }, 120));
  json out;
  out["results_version"] = kResultsVersion;
  out["post"] = masked(post.body, id, "\n");
  const HttpResponse status = s.call("GET", "/v1/jobs/" + id);
  EXPECT_EQ(status.status, 200);
  out["status"] = masked(status.body, id, "\n");
  const HttpResponse list = s.call("GET", "/v1/jobs");
  out["list"] = masked(list.body, id, "\n");
  out["events_replay"] = s.events(id, {{"last-event-id", std::to_string(s.manager->epoch() * 1'000'000'000ULL)}});
  out["events_snapshot"] = s.events(id, {});
  const json st = json::parse(status.body);
  if (st.at("links").contains("image_png")) {
    const HttpResponse tile = s.call("GET", "/v1/jobs/" + id + "/tiles/0");
    EXPECT_EQ(tile.status, 200);
    out["tile0"] = masked(tile.body, id, "\n");
#ifdef TALLY_HAVE_IMAGE_IO
    const HttpResponse png = s.call("GET", "/v1/jobs/" + id + "/image.png");
    EXPECT_EQ(png.status, 200);
    out["png"] = {{"bytes", png.body.size()}, {"fnv1a64", fnv1a64(png.body)}};
    const HttpResponse exr = s.call("GET", "/v1/jobs/" + id + "/image.exr");
    EXPECT_EQ(exr.status, 200);
    // The EXR header carries the job id and OpenEXR's capDate (the clock): mask
    // both with bytes of the same length.
    std::string exr_bytes = replace_all(whole_body(exr), id, std::string(id.size(), '0'));
    if (const size_t at = exr_bytes.find("capDate"); at != std::string::npos) {
      static const std::regex date("[0-9]{4}:[0-9]{2}:[0-9]{2} [0-9]{2}:[0-9]{2}:[0-9]{2}");
      std::smatch m;
      const std::string head = exr_bytes.substr(at, 64);
      if (std::regex_search(head, m, date)) exr_bytes.replace(at + m.position(0), m.length(0), m.length(0), '0');
    }
    out["exr"] = {{"bytes", exr_bytes.size()}, {"fnv1a64", fnv1a64(exr_bytes)}};
    if (const char* dir = std::getenv("TALLY_GOLDEN_DUMP")) {
      std::ofstream(std::string(dir) + "/" + name + ".exr", std::ios::binary) << exr_bytes;
    }
#endif
  }
  return out;
}

class Golden : public ::testing::TestWithParam<std::string> {};

// What a golden output says was computed: channel 0's bits and, for images, the bytes.
json result_bits(const json& out) {
  json r = {{"bits", json::parse(out.at("status").get<std::string>()).at("bits")}};
  for (const char* key : {"png", "exr"}) {
    if (out.contains(key)) r[key] = out.at(key);
  }
  return r;
}

TEST_P(Golden, OutputsAreByteIdentical) {
  const std::string name = GetParam();
  const json got = run_example(name);
  const std::string path = std::string(TALLY_SOURCE_DIR) + "/tests/golden/data/" + name + ".json";
  if (std::getenv("TALLY_UPDATE_GOLDEN")) {
    if (std::ifstream(path).good()) {
      const json old = json::parse(read_file(path));
      if (old.value("results_version", 0u) == kResultsVersion && result_bits(old) != result_bits(got)) {
        FAIL() << name << ": the results changed under results version " << kResultsVersion
               << ". Bump kResultsVersion in common/engine/results_version.hpp, then regenerate.\nwas "
               << result_bits(old).dump() << "\nnow " << result_bits(got).dump();
      }
    }
    std::ofstream(path, std::ios::binary) << got.dump(1) << "\n";
    GTEST_SKIP() << "wrote " << path;
  }
  const json want = json::parse(read_file(path));
  ASSERT_EQ(want.size(), got.size());
  for (auto it = want.begin(); it != want.end(); ++it) {
    ASSERT_TRUE(got.contains(it.key())) << it.key();
    if (it.value().is_array()) {
      const json& g = got.at(it.key());
      ASSERT_EQ(it.value().size(), g.size()) << it.key();
      for (size_t i = 0; i < g.size(); ++i) EXPECT_EQ(it.value()[i], g[i]) << it.key() << "[" << i << "]";
    } else {
      EXPECT_EQ(it.value(), got.at(it.key())) << it.key();
    }
  }
}

// Adaptive and deterministic integration jobs through the HTTP handler (real job
// kinds, the in-process executor with 2 workers) end with the same bits as run_local of
// the same spec on one thread: channel 0's tally, the result document (VEGAS's
// iterations, chi^2, the VEGAS+ allocation; cubature's error estimate) and the estimate.
TEST(ServerJobs, VegasAndCubatureJobsOverHttpEqualRunLocal) {
  const json genz = {{"builtin", "genz"}, {"family", "discontinuous"}, {"a", {3.0, 5.0, 2.0}}, {"u", {0.6, 0.45, 0.5}}};
  const std::vector<json> estimators = {{{"type", "vegas"}},
                                        {{"type", "vegas"}, {"stratify", true}},
                                        {{"type", "cubature"}}};
  Server s;
  for (const json& est : estimators) {
    const json spec = {{"kind", "integrate"},
                       {"seed", 33},
                       {"integrand", genz},
                       {"estimator", est},
                       {"stop", {{"max_samples", est.at("type") == "cubature" ? 50000 : 4096 * 31}}}};
    const HttpResponse post = s.call("POST", "/v1/jobs", dump(spec));
    ASSERT_EQ(post.status, 202) << post.body;
    const std::string id = json::parse(post.body).at("id");
    ASSERT_TRUE(wait_until(
        [&] { return json::parse(s.call("GET", "/v1/jobs/" + id).body).at("state") == "succeeded"; }, 120));
    const HttpResponse status = s.call("GET", "/v1/jobs/" + id);
    ASSERT_EQ(status.status, 200);
    const json st = json::parse(status.body);

    auto job = compile_job(spec, JobLimits{});
    JobRunner local(job->kernel(), job->stop_rule(), JobCaps{});
    run_local(local, 1);
    EXPECT_EQ(st.at("bits"), tally_bits_json(local.state())) << est.dump();
    EXPECT_EQ(st.at("result"), kind_result_json(*job, local)) << est.dump();
    EXPECT_EQ(st.at("samples").get<uint64_t>(), local.state().samples);
    EXPECT_EQ(st.at("estimate").at("mean").get<double>(), local.headline().mean) << est.dump();
    if (est.at("type") == "vegas") {
      EXPECT_EQ(st.at("estimate").at("std_error").get<double>(), local.headline().std_error) << est.dump();
      EXPECT_EQ(st.at("result").at("vegas").contains("hypercubes"), est.contains("stratify"));
    } else {
      EXPECT_TRUE(st.at("result").contains("error_estimate"));
    }
  }
}

INSTANTIATE_TEST_SUITE_P(Examples, Golden,
                         ::testing::Values("unit_disk_expression", "gaussian_uniform", "gaussian_qmc", "inv_sqrt_importance",
                                           "lecture_lighting_point", "preview_image", "lecture_lighting_image"));

// golden.<backend>_module: the module ctest asked for is the one loaded.
TEST(ImageModule, IsTheOneRequested) { test::expect_the_requested_image_module(); }

}  // namespace
}  // namespace tally::test
