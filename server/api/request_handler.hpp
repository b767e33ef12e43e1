#pragma once
// Turns an HttpRequest into an HttpResponse: routing, content negotiation, JSON
// parsing with a depth pre-scan, and the one place that maps failures (SpecError,
// JobError, HttpError) to statuses and problem+json bodies. No sockets here.
// The route bodies live beside it: job_routes.cpp, image_routes.cpp (and the
// health/metrics/openapi routes in add_routes). Routes read JobSnapshots.
#include <atomic>
#include <chrono>
#include <filesystem>
#include <functional>
#include <map>
#include <mutex>
#include <nlohmann/json.hpp>
#include <string>

#include "common/engine/image_source.hpp"
#include "server/auth/authorize.hpp"
#include "server/http/http_handler.hpp"
#include "server/http/http_types.hpp"
#include "server/jobs/job_manager.hpp"
#include "server/api/metrics.hpp"
#include "server/api/router.hpp"

namespace tally {

class AssetStore;

struct ImageEncoders {
  // Writes the EXR of `state`'s image to a file (write_exr_file: a strip at a time); the
  // route sends the file and unlinks it.
  std::function<void(const ImageSource&, const JobState&, const nlohmann::json& metadata,
                     const std::filesystem::path&)>
      exr_file;
  std::function<std::string(const ImageSnapshot&)> png;
};

struct HandlerConfig {
  size_t max_json_depth = 64;
  double pilot_seconds = 0.3;
  unsigned max_concurrent_pilots = 2;
  ImageEncoders images;  // empty functions: the image routes answer 501
  AccessPolicy access;   // who may call (server/auth/authorize.hpp); default: no access control
  // Cluster mode: GET /v1/workers body and extra /metrics lines (server/cluster/cluster_http.hpp).
  std::function<nlohmann::json()> workers;
  std::function<std::string()> extra_metrics;
  // The content-addressed asset store (PUT/HEAD /v1/assets/...); null: those routes answer 404.
  AssetStore* assets = nullptr;
};

// GET /v1/jobs/{id} bodies, kept until the job changes (its version) and, for a
// running job, at most 1 s (its timing fields follow the clock). Thread-safe.
class StatusCache {
 public:
  std::string body(const JobSnapshot& job, const std::function<std::string()>& build);

 private:
  struct Entry {
    uint64_t version = 0;
    std::string body;
    std::chrono::steady_clock::time_point at{};
  };
  static constexpr size_t kMaxEntries = 4096;  // then it starts over
  std::mutex mu_;
  std::map<std::string, Entry> entries_;
};

// GET /v1/jobs pages (docs/api.md).
inline constexpr uint64_t kListDefaultLimit = 100;
inline constexpr uint64_t kListMaxLimit = 1000;

// The application's side of the HTTP interface (server/http/http_handler.hpp).
class RequestHandler final : public HttpHandler {
 public:
  RequestHandler(JobManager& manager, Metrics& metrics, HandlerConfig config);

  HttpResponse handle(HttpRequest request) override;
  // Where the session runs a request (http_types.hpp): compiles and image encodes
  // on the blocking pool, validate pilots on their own slow lane.
  Lane lane(const HttpRequest& request) const override;
  // Streamed bodies (asset uploads): true when the session should not read this
  // request's body into a string but call open_body_stream once its header is read.
  bool streams_body(const HttpRequest& head) const override;
  // Authorizes the request and opens its body's sink (server/api/asset_routes.cpp),
  // or answers at once. Cheap: may run on an I/O thread.
  BodyStream open_body_stream(HttpRequest head) override;
  const Router& router() const { return router_; }
  void set_ready(bool ready) { ready_ = ready; }

 private:
  void add_routes();
  nlohmann::json parse_json_body(const ApiRequest& request) const;
  // Routing, the authorize step and the one mapping of failures to problem responses;
  // `run` is called with the matched route once the caller is authorized.
  HttpResponse guarded(ApiRequest& request, const std::function<HttpResponse(const RouteMatch&)>& run);
  // 422 naming the first "sha256:" reference of `spec` the caller cannot use (not
  // stored, or stored only by another tenant: indistinguishable).
  void check_assets(const ApiRequest& request, const nlohmann::json& spec) const;
  // JobLimits::may_read_asset for `p`: the stored assets it uploaded (every one for an
  // admin), so a "sha256:" name inside a glTF or OBJ is checked as one in the spec.
  std::function<bool(std::string_view)> asset_reader_of(const Principal& p) const;
  // A principal restricted to worker pools (auth file "pools") names one of them in
  // the spec's "pool": else 403 naming /pool.
  void check_pool(const ApiRequest& request, const nlohmann::json& spec) const;
  // The one lookup of every job route: the job if the caller may see it, else 404
  // (another tenant's job is indistinguishable from a missing one).
  std::shared_ptr<Job> visible_job(const ApiRequest& request, const std::string& id) const;
  JobSnapshot visible_snapshot(const ApiRequest& request, const std::string& id,
                               JobManager::SnapshotOf of = JobManager::SnapshotOf::views) const;
  // The server's limits tightened by the caller's quotas.
  Submitter submitter(const ApiRequest& request) const;

  HttpResponse post_job(const ApiRequest&, const PathParams&);
  HttpResponse list_jobs(const ApiRequest&, const PathParams&);
  HttpResponse get_job(const ApiRequest&, const PathParams&);
  HttpResponse delete_job(const ApiRequest&, const PathParams&);
  HttpResponse patch_job(const ApiRequest&, const PathParams&);
  HttpResponse extend_job(const ApiRequest&, const PathParams&);
  HttpResponse validate_job(const ApiRequest&, const PathParams&);
  HttpResponse job_events(const ApiRequest&, const PathParams&);
  HttpResponse job_tile(const ApiRequest&, const PathParams&);
  HttpResponse job_image(const ApiRequest&, const PathParams&, bool exr);
  HttpResponse login(const ApiRequest&, const PathParams&);
  HttpResponse whoami(const ApiRequest&, const PathParams&);
  HttpResponse logout(const ApiRequest&, const PathParams&);
  HttpResponse put_asset(const ApiRequest&, const PathParams&);
  HttpResponse head_asset(const ApiRequest&, const PathParams&);
  std::unique_ptr<BodySink> asset_sink(const ApiRequest&, const PathParams&);

  JobManager& manager_;
  Metrics& metrics_;
  HandlerConfig config_;
  Router router_;
  std::atomic<bool> ready_{true};
  std::atomic<unsigned> pilots_{0};
  StatusCache status_cache_;
};

// The OpenAPI 3.1 document (docs/openapi.json, embedded at build time).
const std::string& openapi_document();

}  // namespace tally
