#pragma once
// The --auth-file: the principals an operator allows, as JSON (docs/security.md):
//   {"principals": [{"name": "alice", "role": "user",
//                    "token_sha256": "<64 hex digits>",
//                    "quotas": {"max_running_jobs": 2, "max_queued_jobs": 8,
//                               "max_samples": 1000000000, "max_seconds": 600,
//                               "max_pixels": 4194304,
//                               "requests_per_second": 20, "burst": 40}}]}
// Only the token's hash is stored. Unknown fields are errors (with the JSON pointer).
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "server/auth/principal.hpp"

namespace tally {

struct PrincipalEntry {
  std::string name;
  Role role = Role::user;
  std::string token_sha256;  // lower-case hex
  Quotas quotas;
  std::vector<std::string> pools;  // "pools": the only worker pools its jobs may name (empty: any)
};

struct AuthFile {
  std::vector<PrincipalEntry> principals;
};

// Throws SpecError naming the field (JSON pointer) on bad content.
AuthFile parse_auth_file(const nlohmann::json& j);
// Reads and parses; throws std::runtime_error with the path and the reason.
AuthFile load_auth_file(const std::string& path);
// The JSON entry to add to the file for a principal (what `token new` prints).
nlohmann::json principal_entry_json(const PrincipalEntry& e);

}  // namespace tally
