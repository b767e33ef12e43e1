#pragma once
// The one place the CLI's server commands share: the default server URL, requests
// that wait out a busy server (503 + Retry-After), and "GET this, expect 200 and JSON"
// with the problem+json detail of a refusal.
#include <functional>
#include <nlohmann/json.hpp>
#include <string>

#include "client/http_client.hpp"

namespace tally {

inline constexpr const char* kDefaultServer = "http://127.0.0.1:8080";

// The problem+json `detail` (prefixed by its JSON pointer), or the body as it came.
std::string problem_detail(const ClientResponse& r);

// How long to wait out 503 answers that carry Retry-After (a server recovering its jobs,
// a full queue, too many validates). Each wait is max(Retry-After, backoff) capped at
// `max_wait_s`, the backoff doubling from `first_backoff_s`; after `budget_s` of waiting
// the 503 is returned. A 503 without Retry-After is returned at once.
struct RetryPolicy {
  double budget_s = 60.0;
  double first_backoff_s = 0.5;
  double max_wait_s = 10.0;
  std::function<void(const ClientResponse&, double wait_s)> on_retry;  // e.g. a note on stderr
};

// client.request(...), retried as `policy` says on 503 + Retry-After.
ClientResponse request_retrying(HttpClient& client, std::string_view method, std::string_view target,
                                std::string_view body = {}, const HeaderList& headers = {},
                                const RetryPolicy& policy = {});

// GET `target` (retrying 503 as RetryPolicy{} says); a status other than 200 goes to
// `refused`, which must throw.
nlohmann::json get_json(HttpClient& client, const std::string& target,
                        const std::function<void(const ClientResponse&)>& refused);

}  // namespace tally
