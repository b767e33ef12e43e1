#pragma once
// The one place the CLI's server commands share: the default server URL and
// "GET this, expect 200 and JSON" with the problem+json detail of a refusal.
#include <functional>
#include <nlohmann/json.hpp>
#include <string>

#include "client/http_client.hpp"

namespace tally {

inline constexpr const char* kDefaultServer = "http://127.0.0.1:8080";

// The problem+json `detail` (prefixed by its JSON pointer), or the body as it came.
std::string problem_detail(const ClientResponse& r);

// GET `target`; a status other than 200 goes to `refused`, which must throw.
nlohmann::json get_json(HttpClient& client, const std::string& target,
                        const std::function<void(const ClientResponse&)>& refused);

}  // namespace tally
