#pragma once
// The route table: (method, pattern) -> handler. Patterns use {name} segments,
// e.g. "/v1/jobs/{id}/events". Literal segments win over parameters. The table is
// also what the OpenAPI test compares docs/openapi.json against and what metrics
// label requests with.
#include <functional>
#include <map>
#include <string>
#include <string_view>
#include <vector>

#include "server/api/api_request.hpp"
#include "server/http/http_types.hpp"

namespace tally {

using PathParams = std::map<std::string, std::string, std::less<>>;
using RouteHandler = std::function<HttpResponse(const ApiRequest&, const PathParams&)>;

struct Route {
  std::string method;
  std::string pattern;
  RouteHandler handler;
  Lane lane = Lane::io;  // where it runs (http_types.hpp): off the I/O threads if it compiles, pilots or encodes
  std::vector<std::string> segments;  // the pattern split at '/', "{x}" = parameter
};

struct RouteMatch {
  const Route* route = nullptr;  // null: see `allow`
  PathParams params;
  std::vector<std::string> allow;  // non-empty: the path exists with other methods (405)
};

class Router {
 public:
  void add(std::string method, std::string pattern, RouteHandler handler, Lane lane = Lane::io);
  RouteMatch match(std::string_view method, std::string_view path) const;
  const std::vector<Route>& routes() const { return routes_; }

 private:
  std::vector<Route> routes_;
};

}  // namespace tally
