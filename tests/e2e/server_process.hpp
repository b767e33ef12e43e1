#pragma once
// Starts the real tally-server on 127.0.0.1 with an ephemeral port (it writes the
// bound port to --port-file) and a temporary data dir; stops it with SIGTERM or
// SIGKILL. Every wait is bounded.
#include <signal.h>
#include <sys/types.h>

#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "client/http_client.hpp"

namespace tally::e2e {

// Starts `args` (argv[0] by path or looked up in PATH) with stdout and stderr appended
// to `log`; returns its pid. The one process launcher of the process tests and the
// cluster benchmark.
// `env`: NAME=value entries added to the child's environment.
pid_t spawn_logged(const std::vector<std::string>& args, const std::filesystem::path& log,
                   const std::vector<std::string>& env = {});

struct TempDir {
  TempDir();
  ~TempDir();
  std::filesystem::path path;
};

class ServerProcess {
 public:
  // `data_dir` persists across restarts; `extra` are more command-line flags.
  ServerProcess(std::filesystem::path data_dir, std::vector<std::string> extra = {});
  ~ServerProcess();

  void start();
  // SIGTERM and wait; returns the exit status (-1 on timeout, then SIGKILL).
  int terminate(double timeout_s = 20);
  void kill9();
  // Sends `sig` (e.g. SIGHUP) to the running server.
  void signal(int sig);
  bool running() const { return pid_ > 0; }
  pid_t pid() const { return pid_; }
  uint16_t port() const { return port_; }
  HttpClient client(double timeout_s = 30) const;
  // A client for this server with credentials; `tls`: https with the given CA file.
  HttpClient client(ClientSecurity security, bool tls = false, double timeout_s = 30) const;
  std::string log() const;

 private:
  std::filesystem::path data_dir_;
  std::vector<std::string> extra_;
  std::filesystem::path port_file_, log_file_;
  pid_t pid_ = -1;
  uint16_t port_ = 0;
};

// Helpers over HttpClient.
nlohmann::json get_json(HttpClient& c, const std::string& target);
std::string submit(HttpClient& c, const nlohmann::json& spec, const std::string& query = "");
// Polls GET /v1/jobs/{id} until its state is `state` (bounded). Returns the status.
nlohmann::json wait_state(HttpClient& c, const std::string& id, const std::string& state, double timeout_s = 90);
nlohmann::json disk_spec(uint64_t max_samples, uint64_t seed = 1);

}  // namespace tally::e2e
