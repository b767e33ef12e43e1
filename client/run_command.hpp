#pragma once
#include <CLI/CLI.hpp>

namespace tally {

// `tally run job.json`: runs a job in-process with the embedded engine (no server).
void add_run_command(CLI::App& app, int& exit_code);

}  // namespace tally
