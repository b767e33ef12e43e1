#pragma once
// Request framing rules the Beast parser leaves to us (socket-free, no Beast):
// RFC 9112 §6.1/§6.3. A Transfer-Encoding whose final coding is not chunked makes
// the body length undeterminable (a proxy in front may see a different request
// boundary: request smuggling) -> 400 and close. Any coding other than chunked is
// not implemented -> 501 and close. Host field rules (RFC 9112 §3.2) -> 400.
#include <optional>
#include <string>
#include <string_view>

namespace tally {

struct FramingProblem {
  int status;
  std::string detail;
};

// RFC 9112 §3.2: a request with more than one Host field line, or an HTTP/1.1 request
// with none, is 400 (the authority it names is ambiguous or missing; with two, one check
// could read the first and another the second). HTTP/1.0 may omit Host.
// `host_fields`: how many Host field lines the request has; `version`: 10 or 11.
std::optional<FramingProblem> host_problem(size_t host_fields, unsigned version);

// `te` is the Transfer-Encoding field value of a request (all of its field lines
// joined with ", "); empty means absent.
std::optional<FramingProblem> transfer_encoding_problem(std::string_view te);

}  // namespace tally
