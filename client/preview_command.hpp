#pragma once
// `tally preview ID --tev HOST:PORT`: follows a job's event stream and mirrors its
// image into a running tev viewer through client/tev_bridge.hpp. Tiles named by
// `tile` events are fetched from GET /v1/jobs/{id}/tiles/{n} at most every 250 ms
// (less often as the image converges) and coalesced; the stream resumes with
// Last-Event-ID after a dropped connection.
#include <CLI/CLI.hpp>
#include <string>

#include "client/api_request.hpp"

namespace tally {

struct PreviewOptions {
  std::string server = kDefaultServer;
  std::string job_id;
  std::string tev = "127.0.0.1:14158";  // HOST:PORT ([v6]:PORT too)
  std::string image_name;               // default "tally-<job id>"
  int tev_retries = 6;
  double min_interval_s = 0.25;
  bool quiet = false;
};

// Returns a client/exit_codes.hpp code.
int run_preview(const PreviewOptions& options);

void add_preview_command(CLI::App& app, int& exit_code);

}  // namespace tally
