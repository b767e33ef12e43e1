#pragma once
// The server commands of the `tally` CLI: submit, watch, get, list, cancel, delete,
// priority, extend.
// `--server URL` or TALLY_SERVER (default http://127.0.0.1:8080). Exit codes are in
// client/exit_codes.hpp and docs/api.md.
#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>
#include <string>

namespace tally {

class HttpClient;

void add_remote_commands(CLI::App& app, int& exit_code);

// Exit code for a job status document (GET /v1/jobs/{id}): 0 done and target met
// (or no target), 2 target not met, 3 failed or cancelled; -1 while unfinished.
int exit_code_for_status(const nlohmann::json& status);

// Follows a job's event stream until it ends, drawing progress on stderr and
// reconnecting with Last-Event-ID if the connection drops. Returns the exit code.
int watch_job(HttpClient& client, const std::string& id, bool quiet = false);

}  // namespace tally
