#pragma once
// The files tally-server serves besides the API: the browser preview page
// (client/preview/) at `/` and `/preview/*`, and the bundled job specs
// (examples/*.json) at `/examples/*` with a generated `/examples/index.json`.
// They are embedded into the binary at build time (server/static_files.cmake),
// so a container needs nothing beside the executable.
//
// Caching: index.html and the examples are revalidated on every load
// (Cache-Control: no-cache + ETag, 304 on If-None-Match); index.html names its
// assets with `?v=<content hash>`, and a request carrying the current hash is
// cacheable for a year (immutable).
#include <cstddef>
#include <optional>
#include <string_view>

#include "server/http/http_types.hpp"

namespace tally {

struct EmbeddedFile {
  std::string_view path;  // relative to the repository, e.g. "client/preview/app.js"
  const unsigned char* data;
  size_t size;
};

// The files embedded at build time (defined in the generated static_assets.cpp).
extern const EmbeddedFile kEmbeddedFiles[];
extern const size_t kEmbeddedFileCount;

// A response for GET or HEAD of a static file, or nullopt when `request` is not
// for one (the caller then answers 404/405 as usual).
std::optional<HttpResponse> serve_static_file(const HttpRequest& request);

// Content-Type for a file name, from its extension.
std::string_view content_type_for(std::string_view name);

}  // namespace tally
