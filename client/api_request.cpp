#include "client/api_request.hpp"

#include <algorithm>
#include <charconv>
#include <chrono>
#include <stdexcept>
#include <thread>

namespace tally {

using nlohmann::json;

std::string problem_detail(const ClientResponse& r) {
  std::string detail = r.body;
  try {
    const json p = json::parse(r.body);
    detail = p.value("detail", r.body);
    if (p.contains("pointer") && !p["pointer"].get<std::string>().empty()) {
      detail = p["pointer"].get<std::string>() + ": " + detail;
    }
  } catch (const std::exception&) {
    detail = r.body;  // not problem+json (a proxy's page, say): show the body as it came
  }
  while (!detail.empty() && detail.back() == '\n') detail.pop_back();
  return detail;
}

namespace {

// Retry-After in seconds (RFC 9110 §10.2.3: delay-seconds; an HTTP date is not used by tally-server).
std::optional<double> retry_after_s(const ClientResponse& r) {
  const std::string v = r.header("Retry-After");
  long s = 0;
  const auto [end, ec] = std::from_chars(v.data(), v.data() + v.size(), s);
  if (v.empty() || ec != std::errc() || end != v.data() + v.size() || s < 0) return std::nullopt;
  return static_cast<double>(s);
}

}  // namespace

ClientResponse request_retrying(HttpClient& client, std::string_view method, std::string_view target,
                                std::string_view body, const HeaderList& headers, const RetryPolicy& policy) {
  double waited = 0, backoff = policy.first_backoff_s;
  for (;;) {
    ClientResponse r = client.request(method, target, body, headers);
    const auto after = r.status == 503 ? retry_after_s(r) : std::nullopt;
    if (!after) return r;
    const double wait = std::min(std::max(*after, backoff), policy.max_wait_s);
    if (waited + wait > policy.budget_s) return r;
    if (policy.on_retry) policy.on_retry(r, wait);
    std::this_thread::sleep_for(std::chrono::duration<double>(wait));
    waited += wait;
    backoff = std::min(backoff * 2, policy.max_wait_s);
  }
}

json get_json(HttpClient& client, const std::string& target, const std::function<void(const ClientResponse&)>& refused) {
  const ClientResponse r = request_retrying(client, "GET", target);
  if (r.status != 200) {
    refused(r);
    throw std::logic_error("get_json: the refusal handler returned");  // it must throw
  }
  return json::parse(r.body);
}

}  // namespace tally
