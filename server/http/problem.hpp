#pragma once
// RFC 9457 problem details: every error response of the API is built here, so the
// mapping from failure to HTTP status lives in one place.
#include <stdexcept>
#include <string>
#include <vector>

#include "server/http/http_types.hpp"

namespace tally {

// Thrown by route handlers; the request handler turns it into a problem response.
class HttpError : public std::runtime_error {
 public:
  HttpError(int status, std::string detail, std::string pointer = {})
      : std::runtime_error(detail), status_(status), detail_(std::move(detail)), pointer_(std::move(pointer)) {}
  int status() const noexcept { return status_; }
  const std::string& detail() const noexcept { return detail_; }
  const std::string& pointer() const noexcept { return pointer_; }
  // Extra headers for the response (Allow, Retry-After).
  std::vector<std::pair<std::string, std::string>> headers;

 private:
  int status_;
  std::string detail_;
  std::string pointer_;
};

// `pointer` is only included when non-empty or `with_pointer` (SpecError of the
// whole document has the pointer "").
HttpResponse problem_response(int status, const std::string& detail, const std::string& pointer = {},
                              bool with_pointer = false);
const char* status_title(int status);
// Stable problem type URI per status, e.g. "https://tally.dev/problems/invalid-spec".
std::string problem_type(int status);

}  // namespace tally
