#pragma once
// A request as the routes see it: the transport's HttpRequest and the caller, which
// the request handler's authorize step sets before any route runs. The transport
// (server/http) knows nothing of principals; this is where the application adds them.
#include <memory>
#include <utility>

#include "server/auth/principal.hpp"
#include "server/http/http_types.hpp"

namespace tally {

struct ApiRequest : HttpRequest {
  explicit ApiRequest(HttpRequest request) : HttpRequest(std::move(request)) {}
  std::shared_ptr<const Principal> principal;  // null only before authorize has run
};

}  // namespace tally
