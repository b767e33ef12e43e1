#include "server_process.hpp"

#include <fcntl.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <thread>

namespace tally::e2e {

using nlohmann::json;
namespace fs = std::filesystem;

pid_t spawn_logged(const std::vector<std::string>& args, const fs::path& log) {
  const pid_t pid = ::fork();
  if (pid < 0) throw std::runtime_error("fork failed");
  if (pid == 0) {
    const int fd = ::open(log.c_str(), O_WRONLY | O_CREAT | O_APPEND, 0644);
    if (fd >= 0) {
      ::dup2(fd, 1);
      ::dup2(fd, 2);
    }
    std::vector<char*> argv;
    for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
    argv.push_back(nullptr);
    ::execvp(argv[0], argv.data());
    ::_exit(127);
  }
  return pid;
}

TempDir::TempDir() {
  static int counter = 0;
  path = fs::temp_directory_path() / ("tally_e2e_" + std::to_string(::getpid()) + "_" + std::to_string(counter++));
  fs::remove_all(path);
  fs::create_directories(path);
}
TempDir::~TempDir() {
  std::error_code ec;
  fs::remove_all(path, ec);
}

ServerProcess::ServerProcess(fs::path data_dir, std::vector<std::string> extra)
    : data_dir_(std::move(data_dir)), extra_(std::move(extra)) {
  port_file_ = data_dir_.parent_path() / (data_dir_.filename().string() + ".port");
  log_file_ = data_dir_.parent_path() / (data_dir_.filename().string() + ".log");
  start();
}

ServerProcess::~ServerProcess() {
  if (pid_ > 0) kill9();
}

void ServerProcess::start() {
  fs::remove(port_file_);
  std::vector<std::string> args = {TALLY_SERVER_BIN, "--listen", "127.0.0.1:0", "--port-file", port_file_.string(),
                                   "--data-dir", data_dir_.string(), "--workers", "2"};
  args.insert(args.end(), extra_.begin(), extra_.end());
  pid_ = spawn_logged(args, log_file_);
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(30);
  while (std::chrono::steady_clock::now() < deadline) {
    std::ifstream in(port_file_);
    unsigned p = 0;
    if (in >> p && p > 0) {
      port_ = static_cast<uint16_t>(p);
      return;
    }
    int status = 0;
    if (::waitpid(pid_, &status, WNOHANG) == pid_) {
      pid_ = -1;
      throw std::runtime_error("tally-server exited at start:\n" + log());
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  throw std::runtime_error("tally-server did not write its port in 30 s:\n" + log());
}

int ServerProcess::terminate(double timeout_s) {
  if (pid_ <= 0) return -1;
  ::kill(pid_, SIGTERM);
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
  int status = 0;
  while (std::chrono::steady_clock::now() < deadline) {
    if (::waitpid(pid_, &status, WNOHANG) == pid_) {
      pid_ = -1;
      return WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  kill9();
  return -1;
}

void ServerProcess::kill9() {
  if (pid_ <= 0) return;
  ::kill(pid_, SIGKILL);
  int status = 0;
  ::waitpid(pid_, &status, 0);
  pid_ = -1;
}

void ServerProcess::signal(int sig) {
  if (pid_ > 0) ::kill(pid_, sig);
}

HttpClient ServerProcess::client(ClientSecurity security, bool tls, double timeout_s) const {
  HttpUrl u;
  u.host = "127.0.0.1";
  u.port = std::to_string(port_);
  u.tls = tls;
  return HttpClient(u, timeout_s, std::move(security));
}

HttpClient ServerProcess::client(double timeout_s) const {
  HttpUrl u;
  u.host = "127.0.0.1";
  u.port = std::to_string(port_);
  return HttpClient(u, timeout_s);
}

std::string ServerProcess::log() const {
  std::ifstream in(log_file_);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

json get_json(HttpClient& c, const std::string& target) {
  const ClientResponse r = c.request("GET", target);
  if (r.status != 200) throw std::runtime_error("GET " + target + ": " + std::to_string(r.status) + " " + r.body);
  return json::parse(r.body);
}

std::string submit(HttpClient& c, const json& spec, const std::string& query) {
  const ClientResponse r = c.request("POST", "/v1/jobs" + query, spec.dump(), {{"Content-Type", "application/json"}});
  if (r.status != 202) throw std::runtime_error("submit: " + std::to_string(r.status) + " " + r.body);
  return json::parse(r.body).at("id").get<std::string>();
}

json wait_state(HttpClient& c, const std::string& id, const std::string& state, double timeout_s) {
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
  json s;
  while (std::chrono::steady_clock::now() < deadline) {
    s = get_json(c, "/v1/jobs/" + id);
    if (s.at("state") == state) return s;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  throw std::runtime_error("job " + id + " did not reach " + state + "; last: " + s.value("state", "?"));
}

json disk_spec(uint64_t max_samples, uint64_t seed) {
  return {{"kind", "integrate"},
          {"integrand", {{"builtin", "unit_disk"}}},
          {"domain", {{"type", "box"}, {"lower", {-1, -1}}, {"upper", {1, 1}}}},
          {"estimator", {{"type", "uniform"}}},
          {"seed", seed},
          {"stop", {{"max_samples", max_samples}}}};
}

}  // namespace tally::e2e
