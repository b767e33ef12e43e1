#include "server/http/http_framing.hpp"

#include <algorithm>
#include <vector>

#include "server/http/http_types.hpp"

namespace tally {

namespace {

std::string_view trim(std::string_view s) {
  while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) s.remove_prefix(1);
  while (!s.empty() && (s.back() == ' ' || s.back() == '\t')) s.remove_suffix(1);
  return s;
}

}  // namespace

std::optional<FramingProblem> host_problem(size_t host_fields, unsigned version) {
  if (host_fields > 1) {
    return FramingProblem{400, "the request has more than one Host header (RFC 9112 section 3.2)"};
  }
  if (host_fields == 0 && version >= 11) {
    return FramingProblem{400, "an HTTP/1.1 request needs a Host header (RFC 9112 section 3.2)"};
  }
  return std::nullopt;
}

std::optional<FramingProblem> transfer_encoding_problem(std::string_view te) {
  if (trim(te).empty()) return std::nullopt;
  std::vector<std::string_view> codings;
  size_t i = 0;
  while (i <= te.size()) {
    const size_t j = std::min(te.find(',', i), te.size());
    std::string_view c = trim(te.substr(i, j - i));
    const size_t semi = c.find(';');  // transfer parameters
    if (semi != std::string_view::npos) c = trim(c.substr(0, semi));
    if (!c.empty()) codings.push_back(c);
    i = j + 1;
  }
  if (codings.empty()) return FramingProblem{400, "Transfer-Encoding is present but names no coding"};
  if (!iequals(codings.back(), "chunked")) {
    return FramingProblem{400, "Transfer-Encoding must end with chunked (RFC 9112 section 6.3); the body length "
                               "cannot be determined"};
  }
  for (size_t k = 0; k + 1 < codings.size(); ++k) {
    if (iequals(codings[k], "chunked")) {
      return FramingProblem{400, "Transfer-Encoding applies chunked more than once"};
    }
    return FramingProblem{501, "Transfer-Encoding: only chunked is implemented, got \"" + std::string(codings[k]) + "\""};
  }
  return std::nullopt;
}

}  // namespace tally
