#pragma once
// Request framing rules the Beast parser leaves to us (socket-free, no Beast):
// RFC 9112 §6.1/§6.3. A Transfer-Encoding whose final coding is not chunked makes
// the body length undeterminable (a proxy in front may see a different request
// boundary: request smuggling) -> 400 and close. Any coding other than chunked is
// not implemented -> 501 and close.
#include <optional>
#include <string>
#include <string_view>

namespace tally {

struct FramingProblem {
  int status;
  std::string detail;
};

// `te` is the Transfer-Encoding field value of a request (all of its field lines
// joined with ", "); empty means absent.
std::optional<FramingProblem> transfer_encoding_problem(std::string_view te);

}  // namespace tally
