#include "client/api_request.hpp"

#include <stdexcept>

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

json get_json(HttpClient& client, const std::string& target, const std::function<void(const ClientResponse&)>& refused) {
  const ClientResponse r = client.request("GET", target);
  if (r.status != 200) {
    refused(r);
    throw std::logic_error("get_json: the refusal handler returned");  // it must throw
  }
  return json::parse(r.body);
}

}  // namespace tally
