#pragma once
// Socket-free request and response types: the request handler turns one into the
// other, so every route is unit-testable without a network. Only the listener and
// session (http_server.cpp) know about Beast.
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

namespace tally {

class EventStream;

// Where a request runs. `io`: on the I/O thread (must be quick); `blocking`: the
// small pool for compiles, submits and image encodes; `slow`: the validate pilots'
// own bounded pool, so a pilot never delays a submit or a GET (a full slow lane
// answers 503 + Retry-After).
enum class Lane { io, blocking, slow };

struct HttpRequest {
  using Headers = std::vector<std::pair<std::string, std::string>>;
  std::string method;  // "GET", "POST", ...
  std::string target;  // path and query, e.g. "/v1/jobs?state=running"
  std::vector<std::pair<std::string, std::string>> headers;  // names in lower case
  std::string body;
  // The client's IP address (no port), set by the listener; empty without a socket.
  // What per-address limits count (behind a reverse proxy: the proxy's address).
  std::string peer_address;

  std::string_view header(std::string_view lower_name) const;
  std::string_view path() const;
  // Decoded value of a query parameter; empty if absent.
  std::string query_param(std::string_view name) const;
  bool has_query_param(std::string_view name) const;
};

struct HttpResponse {
  int status = 200;
  std::vector<std::pair<std::string, std::string>> headers;
  std::string body;
  // Non-null: the body is an unbounded stream (SSE / NDJSON) sent with chunked
  // encoding; `body` is ignored.
  std::shared_ptr<EventStream> stream;

  void set_header(std::string name, std::string value);
  std::string_view header(std::string_view name) const;  // case-insensitive
};

// A request body a route takes as a stream instead of a string (uploads: PUT
// /v1/assets/...). Once the header is read, the session asks the request handler
// for a sink (HttpHandler::open_body_stream) and feeds it the body part by part,
// off the I/O threads, then calls finish(). A sink destroyed without finish() (the
// client went away, a timeout) must undo whatever it wrote.
class BodySink {
 public:
  virtual ~BodySink() = default;
  // The next part of the body; a response ends the request early (e.g. 413).
  virtual std::optional<HttpResponse> write(std::string_view part) = 0;
  // The whole body arrived: the response.
  virtual HttpResponse finish() = 0;
};

// What the handler answers once a streamed request's header is read: a sink for
// the body, or (authorization failed, bad name, too large) the response at once.
struct BodyStream {
  std::unique_ptr<BodySink> sink;
  HttpResponse response;  // used when sink is null
};

std::string url_decode(std::string_view s);
bool iequals(std::string_view a, std::string_view b);

}  // namespace tally
