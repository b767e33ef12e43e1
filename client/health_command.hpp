#pragma once
// `tally health [--server URL] [--timeout S]`: GET /readyz once; exit 0 if the server
// answers 200, else exit_code::connection. The container HEALTHCHECK runs it, so the
// runtime image needs no curl.
#include <CLI/CLI.hpp>

namespace tally {

void add_health_command(CLI::App& app, int& exit_code);

}  // namespace tally
