#include "client/health_command.hpp"

#include <fmt/format.h>

#include <cstdio>
#include <memory>
#include <string>

#include "client/exit_codes.hpp"
#include "client/api_request.hpp"
#include "client/http_client.hpp"

namespace tally {

namespace {

struct HealthOptions {
  std::string server = kDefaultServer;
  std::string path = "/readyz";
  double timeout_s = 3.0;
  bool quiet = false;
};

int check_health(const HealthOptions& o) {
  const auto url = parse_http_url(o.server);
  if (!url) {
    fmt::print(stderr, "tally: --server must be an http:// URL, got \"{}\"\n", o.server);
    return exit_code::usage;
  }
  try {
    HttpClient client(*url, o.timeout_s);
    const ClientResponse r = client.request("GET", o.path);
    if (r.status == 200) {
      if (!o.quiet) fmt::print("{}{}: ok\n", o.server, o.path);
      return exit_code::ok;
    }
    fmt::print(stderr, "tally: {}{} answered {}\n", o.server, o.path, r.status);
  } catch (const std::exception& e) {
    fmt::print(stderr, "tally: {}{}: {}\n", o.server, o.path, e.what());
  }
  return exit_code::connection;
}

}  // namespace

void add_health_command(CLI::App& app, int& exit_code) {
  auto opt = std::make_shared<HealthOptions>();
  CLI::App* cmd = app.add_subcommand("health", "Check that the server is ready (GET /readyz); exit 0 if so");
  cmd->add_option("--server", opt->server, "server URL")->envname("TALLY_SERVER")->capture_default_str();
  cmd->add_option("--path", opt->path, "probe path, e.g. /livez")->capture_default_str();
  cmd->add_option("--timeout", opt->timeout_s, "seconds to wait for the answer")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  cmd->add_flag("--quiet,-q", opt->quiet, "print nothing on success");
  cmd->callback([opt, &exit_code] { exit_code = check_health(*opt); });
}

}  // namespace tally
