// `tally`: the command-line client. Offline `run`; server commands (submit, watch,
// get, list, cancel, extend) live in remote_commands.cpp.
#include <CLI/CLI.hpp>

#include "client/exit_codes.hpp"
#include "client/run_command.hpp"
#if __has_include("client/remote_commands.hpp")
#include "client/remote_commands.hpp"
#define TALLY_HAVE_REMOTE 1
#endif

int main(int argc, char** argv) {
  CLI::App app{"tally: Monte Carlo estimates with honest error bars"};
  app.require_subcommand(1);
  int code = tally::exit_code::ok;
  tally::add_run_command(app, code);
#ifdef TALLY_HAVE_REMOTE
  tally::add_remote_commands(app, code);
#endif
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int rc = app.exit(e);
    return rc == 0 ? 0 : tally::exit_code::usage;
  }
  return code;
}
