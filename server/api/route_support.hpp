#pragma once
// Small helpers the route files share (JSON answers, query/header parsing, job URLs).
#include <fmt/format.h>

#include <charconv>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <string_view>

#include "common/spec/priority_field.hpp"
#include "server/http/problem.hpp"
#include "server/http/http_types.hpp"

namespace tally {

inline HttpResponse json_response(int status, const nlohmann::json& j) {
  HttpResponse r;
  r.status = status;
  r.set_header("Content-Type", "application/json");
  r.body = j.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
  r.body.push_back('\n');
  return r;
}

inline bool is_json_media_type(std::string_view ct) {
  const size_t semi = ct.find(';');
  std::string_view type = ct.substr(0, semi);
  while (!type.empty() && type.back() == ' ') type.remove_suffix(1);
  while (!type.empty() && type.front() == ' ') type.remove_prefix(1);
  if (iequals(type, "application/json")) return true;
  // application/*+json (e.g. a client sending problem+json back at us) is JSON too.
  return type.size() > 17 && iequals(type.substr(0, 12), "application/") && iequals(type.substr(type.size() - 5), "+json");
}

inline std::optional<uint64_t> parse_u64(std::string_view s) {
  while (!s.empty() && s.front() == ' ') s.remove_prefix(1);
  while (!s.empty() && s.back() == ' ') s.remove_suffix(1);
  uint64_t v = 0;
  auto [p, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
  if (ec != std::errc() || p != s.data() + s.size() || s.empty()) return std::nullopt;
  return v;
}

inline int parse_priority(const HttpRequest& req) {
  if (!req.has_query_param("priority")) return 0;
  const std::string p = req.query_param("priority");
  int v = 0;
  auto [ptr, ec] = std::from_chars(p.data(), p.data() + p.size(), v);
  if (ec != std::errc() || ptr != p.data() + p.size() || v < kMinPriority || v > kMaxPriority) {
    throw HttpError(400, fmt::format("query parameter priority must be an integer in [{}, {}], got \"{}\"",
                                     kMinPriority, kMaxPriority, p));
  }
  return v;
}

// The one place job URLs are built. `image`: add the image and tile links.
inline nlohmann::json job_links(const std::string& id, bool image) {
  const std::string self = "/v1/jobs/" + id;
  nlohmann::json links = {{"self", self}, {"events", self + "/events"}};
  if (image) {
    links["image_exr"] = self + "/image.exr";
    links["image_png"] = self + "/image.png";
    links["tiles"] = self + "/tiles/{n}";
  }
  return links;
}

}  // namespace tally
