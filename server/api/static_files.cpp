#include "server/api/static_files.hpp"

#include <fmt/format.h>

#include <map>
#include <nlohmann/json.hpp>
#include <string>

#include "common/hash/fnv1a.hpp"

namespace tally {

namespace {

constexpr std::string_view kPreviewDir = "client/preview/";
constexpr std::string_view kExamplesDir = "examples/";

struct Entry {
  std::string body;
  std::string content_type;
  std::string hash;  // 16 hex digits of FNV-1a 64 over the body
  bool html = false;
};


bool ends_with(std::string_view s, std::string_view suffix) {
  return s.size() >= suffix.size() && s.substr(s.size() - suffix.size()) == suffix;
}

Entry make_entry(std::string body, std::string_view name) {
  Entry e;
  e.content_type = std::string(content_type_for(name));
  e.html = ends_with(name, ".html");
  e.body = std::move(body);
  e.hash = fmt::format("{:016x}", fnv1a64(e.body));
  return e;
}

// index.html names its assets as "{{asset:app.js}}"; each becomes
// "/preview/app.js?v=<hash>" so a changed file is fetched under a new URL.
std::string link_assets(std::string html, const std::map<std::string, Entry, std::less<>>& files) {
  const std::string open = "{{asset:";
  size_t pos = 0;
  while ((pos = html.find(open, pos)) != std::string::npos) {
    const size_t close = html.find("}}", pos);
    if (close == std::string::npos) break;
    const std::string name = html.substr(pos + open.size(), close - pos - open.size());
    const std::string url = "/preview/" + name;
    const auto it = files.find(url);
    const std::string link = it == files.end() ? url : url + "?v=" + it->second.hash;
    html.replace(pos, close + 2 - pos, link);
    pos += link.size();
  }
  return html;
}

// URL path -> file, built once from the embedded files.
const std::map<std::string, Entry, std::less<>>& table() {
  static const std::map<std::string, Entry, std::less<>> files = [] {
    std::map<std::string, Entry, std::less<>> t;
    nlohmann::json examples = nlohmann::json::array();
    std::string index_html;
    for (size_t i = 0; i < kEmbeddedFileCount; ++i) {
      const EmbeddedFile& f = kEmbeddedFiles[i];
      std::string body(reinterpret_cast<const char*>(f.data), f.size);
      if (f.path.starts_with(kPreviewDir)) {
        const std::string_view rel = f.path.substr(kPreviewDir.size());
        if (rel == "index.html") {
          index_html = std::move(body);
          continue;
        }
        t.emplace("/preview/" + std::string(rel), make_entry(std::move(body), rel));
      } else if (f.path.starts_with(kExamplesDir)) {
        const std::string_view rel = f.path.substr(kExamplesDir.size());
        if (rel.find('/') != std::string_view::npos || !ends_with(rel, ".json") || rel == "index.json") continue;
        nlohmann::json item = {{"name", std::string(rel.substr(0, rel.size() - 5))},
                               {"url", "/examples/" + std::string(rel)}};
        // Describe the example from its spec, so the page can show what it is.
        const nlohmann::json spec = nlohmann::json::parse(body, nullptr, false);
        if (spec.is_object()) {
          item["kind"] = spec.value("kind", "");
          const auto q = spec.find("query");
          item["image"] = q != spec.end() && q->is_object() && q->value("type", "") == "image";
        }
        examples.push_back(std::move(item));
        t.emplace("/examples/" + std::string(rel), make_entry(std::move(body), rel));
      }
    }
    t.emplace("/examples/index.json", make_entry(nlohmann::json{{"examples", examples}}.dump(1) + "\n", "index.json"));
    if (!index_html.empty()) {
      Entry e = make_entry(link_assets(std::move(index_html), t), "index.html");
      t.emplace("/preview/index.html", e);
      t.emplace("/", std::move(e));
    }
    return t;
  }();
  return files;
}

// True if an If-None-Match header value lists `etag` (or is "*").
bool etag_matches(std::string_view header, std::string_view etag) {
  if (header.empty()) return false;
  size_t i = 0;
  while (i < header.size()) {
    const size_t comma = header.find(',', i);
    std::string_view tag = header.substr(i, comma == std::string_view::npos ? std::string_view::npos : comma - i);
    while (!tag.empty() && tag.front() == ' ') tag.remove_prefix(1);
    while (!tag.empty() && tag.back() == ' ') tag.remove_suffix(1);
    if (tag.starts_with("W/")) tag.remove_prefix(2);
    if (tag == "*" || tag == etag) return true;
    if (comma == std::string_view::npos) break;
    i = comma + 1;
  }
  return false;
}

}  // namespace

std::string_view content_type_for(std::string_view name) {
  if (ends_with(name, ".html")) return "text/html; charset=utf-8";
  if (ends_with(name, ".js") || ends_with(name, ".mjs")) return "text/javascript; charset=utf-8";
  if (ends_with(name, ".css")) return "text/css; charset=utf-8";
  if (ends_with(name, ".json")) return "application/json";
  if (ends_with(name, ".svg")) return "image/svg+xml";
  if (ends_with(name, ".png")) return "image/png";
  if (ends_with(name, ".txt")) return "text/plain; charset=utf-8";
  return "application/octet-stream";
}

std::optional<HttpResponse> serve_static_file(const HttpRequest& request) {
  if (request.method != "GET") return std::nullopt;
  const auto& files = table();
  const auto it = files.find(request.path());
  if (it == files.end()) return std::nullopt;
  const Entry& e = it->second;
  const std::string etag = "\"" + e.hash + "\"";
  HttpResponse r;
  r.set_header("ETag", etag);
  // A URL carrying the current content hash never changes: cache it for a year.
  // Anything else (the page itself, examples, unversioned asset URLs) is revalidated.
  const bool versioned = request.has_query_param("v") && request.query_param("v") == e.hash;
  r.set_header("Cache-Control", versioned ? "public, max-age=31536000, immutable" : "no-cache");
  r.set_header("X-Content-Type-Options", "nosniff");
  if (e.html) {
    r.set_header("Content-Security-Policy",
                 "default-src 'self'; img-src 'self' data: blob:; style-src 'self'; script-src 'self'; "
                 "connect-src 'self'; frame-ancestors 'none'");
    r.set_header("Referrer-Policy", "no-referrer");
  }
  if (etag_matches(request.header("if-none-match"), etag)) {
    r.status = 304;
    return r;
  }
  r.set_header("Content-Type", e.content_type);
  r.body = e.body;
  return r;
}

}  // namespace tally
