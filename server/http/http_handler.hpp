#pragma once
// What the transport (http_server.cpp) asks of the application: the interface the
// HTTP layer defines and the application's request handler implements, so the listener and
// sessions compile against this and not against the job manager.
#include "server/http/http_types.hpp"

namespace tally {

class HttpHandler {
 public:
  virtual ~HttpHandler() = default;
  // The response to one whole request. Runs on the request's lane.
  virtual HttpResponse handle(HttpRequest request) = 0;
  // Where the session runs a request (http_types.hpp). Cheap: called on an I/O thread.
  virtual Lane lane(const HttpRequest& request) const = 0;
  // True when the session should not read this request's body into a string but call
  // open_body_stream once its header is read. Cheap: called on an I/O thread.
  virtual bool streams_body(const HttpRequest& head) const = 0;
  // The sink for a streamed body, or the response at once. Cheap: called on an I/O thread.
  virtual BodyStream open_body_stream(HttpRequest head) = 0;
};

}  // namespace tally
