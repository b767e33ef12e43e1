#pragma once
// The whole body of a route's response as a client would receive it: `body`, or the
// parts of a finite stream (a file sent in parts: GET .../image.exr) read to its end.
// Not for event streams of running jobs, which do not end.
#include <stdexcept>
#include <string>

#include "server/http/event_stream.hpp"
#include "server/http/http_types.hpp"

namespace tally::test {

inline std::string whole_body(const HttpResponse& r, size_t max_polls = 1'000'000) {
  if (!r.stream) return r.body;
  std::string out;
  for (size_t i = 0; i < max_polls; ++i) {
    if (!r.stream->poll(out)) return out;
  }
  throw std::runtime_error("the response stream did not end");
}

}  // namespace tally::test
