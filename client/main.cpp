// `tally`: the command-line client. Offline `run` (the embedded engine); server
// commands submit/watch/get/list/cancel/extend (remote_commands.cpp), `health`
// (container health checks) and `preview` (the tev bridge).
#include <CLI/CLI.hpp>
#include <string>

#include "client/exit_codes.hpp"
#include "client/health_command.hpp"
#include "client/preview_command.hpp"
#include "client/remote_commands.hpp"
#include "client/run_command.hpp"

int main(int argc, char** argv) {
  CLI::App app{"tally: Monte Carlo estimates with honest error bars"};
  app.set_version_flag("--version", std::string("tally ") + TALLY_VERSION);
  app.require_subcommand(1);
  int code = tally::exit_code::ok;
  tally::add_run_command(app, code);
  tally::add_remote_commands(app, code);
  tally::add_health_command(app, code);
  tally::add_preview_command(app, code);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int rc = app.exit(e);
    return rc == 0 ? 0 : tally::exit_code::usage;
  }
  return code;
}
