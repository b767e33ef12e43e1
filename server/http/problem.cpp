#include "server/http/problem.hpp"

#include <nlohmann/json.hpp>

namespace tally {

const char* status_title(int status) {
  switch (status) {
    case 400: return "Bad Request";
    case 401: return "Unauthorized";
    case 403: return "Forbidden";
    case 404: return "Not Found";
    case 405: return "Method Not Allowed";
    case 406: return "Not Acceptable";
    case 408: return "Request Timeout";
    case 409: return "Conflict";
    case 413: return "Content Too Large";
    case 415: return "Unsupported Media Type";
    case 422: return "Unprocessable Content";
    case 429: return "Too Many Requests";
    case 431: return "Request Header Fields Too Large";
    case 500: return "Internal Server Error";
    case 501: return "Not Implemented";
    case 503: return "Service Unavailable";
    default: return "Error";
  }
}

std::string problem_type(int status) {
  const char* slug = "error";
  switch (status) {
    case 400: slug = "malformed-request"; break;
    case 401: slug = "unauthorized"; break;
    case 403: slug = "forbidden"; break;
    case 404: slug = "not-found"; break;
    case 405: slug = "method-not-allowed"; break;
    case 406: slug = "not-acceptable"; break;
    case 409: slug = "conflict"; break;
    case 413: slug = "body-too-large"; break;
    case 415: slug = "unsupported-media-type"; break;
    case 422: slug = "invalid-spec"; break;
    case 429: slug = "too-many-requests"; break;
    case 431: slug = "headers-too-large"; break;
    case 500: slug = "internal-error"; break;
    case 501: slug = "not-implemented"; break;
    case 503: slug = "unavailable"; break;
    default: break;
  }
  return std::string("https://tally.dev/problems/") + slug;
}

HttpResponse problem_response(int status, const std::string& detail, const std::string& pointer,
                              bool with_pointer) {
  nlohmann::json j;
  j["type"] = problem_type(status);
  j["title"] = status_title(status);
  j["status"] = status;
  j["detail"] = detail;
  if (with_pointer || !pointer.empty()) j["pointer"] = pointer;
  HttpResponse r;
  r.status = status;
  r.set_header("Content-Type", "application/problem+json");
  r.set_header("X-Content-Type-Options", "nosniff");
  r.body = j.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
  r.body.push_back('\n');
  return r;
}

}  // namespace tally
