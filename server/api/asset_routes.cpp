// The asset routes: PUT /v1/assets/sha256:<hex> (streamed into the AssetStore) and
// HEAD /v1/assets/sha256:<hex>; and the submit-time check that a spec's "sha256:"
// references name assets the caller may use. See docs/api.md "Assets".
#include <fmt/format.h>

#include <chrono>

#include "common/lighting/asset_resolver.hpp"
#include "common/spec/spec_reader.hpp"
#include "server/api/request_handler.hpp"
#include "server/api/route_support.hpp"
#include "server/assets/asset_refs.hpp"
#include "server/assets/asset_store.hpp"

namespace tally {

namespace {

int status_of(const AssetError& e) {
  switch (e.kind()) {
    case AssetError::Kind::bad_name: return 400;
    case AssetError::Kind::too_large: return 413;
    case AssetError::Kind::quota: return 403;
    case AssetError::Kind::mismatch: return 422;
    case AssetError::Kind::no_space: return 507;  // Insufficient Storage (RFC 4918): the disk is full
    case AssetError::Kind::io: break;
  }
  return 500;
}

// "sha256:<hex>" -> hex, or 400 naming the rule.
std::string hex_of_name(const std::string& name) {
  if (auto hex = asset_ref_hex(name)) return *hex;
  throw HttpError(400, fmt::format("an asset is named sha256:<64 lowercase hex digits>, got \"{}\"", name));
}

HttpResponse stored_response(bool created, const std::string& hex, uint64_t bytes) {
  HttpResponse r = json_response(created ? 201 : 200, {{"asset", "sha256:" + hex}, {"bytes", bytes}, {"created", created}});
  r.set_header("Location", "/v1/assets/sha256:" + hex);
  return r;
}

class AssetSink : public BodySink {
 public:
  AssetSink(std::unique_ptr<AssetUpload> upload, std::string hex, Metrics& metrics)
      : upload_(std::move(upload)), hex_(std::move(hex)), metrics_(metrics), t0_(std::chrono::steady_clock::now()) {}

  std::optional<HttpResponse> write(std::string_view part) override {
    try {
      upload_->write(part);
      return std::nullopt;
    } catch (const AssetError& e) {
      return done(problem_response(status_of(e), e.what()));
    }
  }

  HttpResponse finish() override {
    try {
      const bool created = upload_->finish();
      return done(stored_response(created, hex_, upload_->bytes()));
    } catch (const AssetError& e) {
      return done(problem_response(status_of(e), e.what()));
    } catch (const std::exception& e) {
      return done(problem_response(500, fmt::format("internal error: {}", e.what())));
    }
  }

 private:
  HttpResponse done(HttpResponse r) {
    r.set_header("X-Content-Type-Options", "nosniff");
    const double dt = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0_).count();
    metrics_.observe("/v1/assets/{name}", "PUT", r.status, dt);
    return r;
  }

  std::unique_ptr<AssetUpload> upload_;
  std::string hex_;
  Metrics& metrics_;
  std::chrono::steady_clock::time_point t0_;
};

std::optional<uint64_t> content_length(const HttpRequest& req) {
  const std::string_view cl = req.header("content-length");
  if (cl.empty()) return std::nullopt;
  return parse_u64(cl);
}

}  // namespace

bool RequestHandler::streams_body(const HttpRequest& head) const {
  if (head.method != "PUT") return false;
  const RouteMatch m = router_.match(head.method, head.path());
  return m.route && m.route->pattern == "/v1/assets/{name}";
}

BodyStream RequestHandler::open_body_stream(HttpRequest http) {
  ApiRequest head(std::move(http));
  BodyStream out;
  out.response = guarded(head, [&](const RouteMatch& m) {
    out.sink = asset_sink(head, m.params);
    HttpResponse continues;
    continues.status = 0;
    return continues;
  });
  return out;
}

std::unique_ptr<BodySink> RequestHandler::asset_sink(const ApiRequest& req, const PathParams& params) {
  if (!config_.assets) throw HttpError(404, "this server has no asset store");
  const std::string hex = hex_of_name(params.at("name"));
  const Principal& p = *req.principal;
  try {
    auto upload = config_.assets->begin(hex, p.name, content_length(req), p.quotas.max_asset_bytes);
    return std::make_unique<AssetSink>(std::move(upload), hex, metrics_);
  } catch (const AssetError& e) {
    throw HttpError(status_of(e), e.what());
  }
}

HttpResponse RequestHandler::put_asset(const ApiRequest& req, const PathParams& params) {
  std::unique_ptr<BodySink> sink = asset_sink(req, params);
  if (auto early = sink->write(req.body)) return *early;
  return sink->finish();
}

HttpResponse RequestHandler::head_asset(const ApiRequest& req, const PathParams& params) {
  if (!config_.assets) throw HttpError(404, "this server has no asset store");
  const std::string hex = hex_of_name(params.at("name"));
  const Principal& p = *req.principal;
  const auto size = config_.assets->find(hex, p.name, p.is_admin());
  HttpResponse r;
  r.status = size ? 200 : 404;  // another tenant's asset is indistinguishable from a missing one
  if (size) r.set_header("X-Asset-Bytes", std::to_string(*size));
  return r;
}

std::function<bool(std::string_view)> RequestHandler::asset_reader_of(const Principal& p) const {
  if (!config_.assets || p.is_admin()) return {};  // admins (and a server without access control) read every asset
  return [store = config_.assets, owner = p.name](std::string_view hex) {
    return store->find(std::string(hex), owner, false).has_value();
  };
}

void RequestHandler::check_assets(const ApiRequest& req, const nlohmann::json& spec) const {
  const std::vector<AssetRef> refs = asset_refs(spec);
  if (refs.empty()) return;
  const Principal& p = *req.principal;
  for (const AssetRef& a : refs) {
    if (!config_.assets || !config_.assets->find(a.hex, p.name, p.is_admin())) {
      throw SpecError(a.pointer, fmt::format("asset sha256:{} is not stored on this server; upload it with PUT "
                                             "/v1/assets/sha256:{}",
                                             a.hex, a.hex));
    }
  }
}

}  // namespace tally
