#include "cluster_process.hpp"
#include "server_process.hpp"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <thread>

namespace tally::e2e {

namespace fs = std::filesystem;
using namespace std::chrono_literals;

namespace {

void reap(pid_t& pid, int sig) {
  if (pid <= 0) return;
  ::kill(pid, SIGCONT);
  ::kill(pid, sig);
  const auto deadline = std::chrono::steady_clock::now() + 10s;
  int status = 0;
  while (std::chrono::steady_clock::now() < deadline) {
    if (::waitpid(pid, &status, WNOHANG) == pid) {
      pid = -1;
      return;
    }
    std::this_thread::sleep_for(5ms);
  }
  ::kill(pid, SIGKILL);
  ::waitpid(pid, &status, 0);
  pid = -1;
}

std::string slurp(const fs::path& p) {
  std::ifstream in(p);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

}  // namespace

RedisServer::RedisServer(fs::path dir, std::vector<std::string> extra, std::string credentials, int tcp_port)
    : dir_(std::move(dir)), socket_(dir_ / "r.sock"), extra_(std::move(extra)), credentials_(std::move(credentials)),
      tcp_port_(tcp_port) {
  start();
}

int free_loopback_port() {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  a.sin_port = 0;
  socklen_t len = sizeof a;
  if (fd < 0 || ::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0 ||
      ::getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len) != 0) {
    if (fd >= 0) ::close(fd);
    throw std::runtime_error("cannot find a free loopback port");
  }
  ::close(fd);
  return ntohs(a.sin_port);
}
RedisServer::~RedisServer() { stop(); }

void RedisServer::start() {
  fs::remove(socket_);
  std::vector<std::string> args = {"redis-server", "--port", std::to_string(tcp_port_), "--bind", "127.0.0.1",
                                   "--unixsocket", socket_.string(), "--save", "", "--appendonly", "no",
                                   "--maxmemory-policy", "noeviction", "--dir", dir_.string()};
  args.insert(args.end(), extra_.begin(), extra_.end());
  pid_ = spawn_logged(args, dir_ / "redis.log");
  const auto deadline = std::chrono::steady_clock::now() + 10s;
  while (std::chrono::steady_clock::now() < deadline) {
    try {
      auto c = connect();
      if (c.cmd({"PING"}).str == "PONG") return;
    } catch (const std::exception&) {
    }
    std::this_thread::sleep_for(10ms);
  }
  throw std::runtime_error("redis-server did not start:\n" + slurp(dir_ / "redis.log"));
}

void RedisServer::stop() { reap(pid_, SIGKILL); }

cluster::RedisConn RedisServer::connect() const { return cluster::RedisConn(cluster::parse_redis_url(url()), 2000ms); }

WorkerProcess::WorkerProcess(std::string url, std::string name, fs::path log_dir, unsigned threads,
                             std::vector<std::string> extra, WorkerOptions options)
    : url_(std::move(url)), name_(std::move(name)), log_(log_dir / (name_ + ".log")), threads_(threads),
      extra_(std::move(extra)), options_(std::move(options)) {
  if (options_.bin.empty()) options_.bin = options_.test_worker ? TALLY_TEST_WORKER_BIN : TALLY_WORKER_BIN;
  start();
}

bool WorkerProcess::exited() {
  if (pid_ <= 0) return true;
  int status = 0;
  if (::waitpid(pid_, &status, WNOHANG) != pid_) return false;
  exit_code_ = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
  pid_ = -1;
  return true;
}
WorkerProcess::~WorkerProcess() { reap(pid_, SIGKILL); }

void WorkerProcess::start() {
  std::vector<std::string> args = {options_.bin, "--redis", url_, "--name", name_, "--threads",
                                   std::to_string(threads_)};
  args.insert(args.end(), extra_.begin(), extra_.end());
  exit_code_ = -1;
  pid_ = spawn_logged(args, log_, options_.env);
}
void WorkerProcess::kill9() { reap(pid_, SIGKILL); }
void WorkerProcess::pause() {
  if (pid_ > 0) ::kill(pid_, SIGSTOP);
}
void WorkerProcess::resume() {
  if (pid_ > 0) ::kill(pid_, SIGCONT);
}
int WorkerProcess::terminate() {
  if (pid_ <= 0) return -1;
  ::kill(pid_, SIGTERM);
  int status = 0;
  const auto deadline = std::chrono::steady_clock::now() + 10s;
  while (std::chrono::steady_clock::now() < deadline) {
    if (::waitpid(pid_, &status, WNOHANG) == pid_) {
      pid_ = -1;
      return WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
    }
    std::this_thread::sleep_for(5ms);
  }
  reap(pid_, SIGKILL);
  return -1;
}
std::string WorkerProcess::log() const { return slurp(log_); }

}  // namespace tally::e2e
