#include "cluster_process.hpp"
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

RedisServer::RedisServer(fs::path dir) : dir_(std::move(dir)), socket_(dir_ / "r.sock") { start(); }
RedisServer::~RedisServer() { stop(); }

void RedisServer::start() {
  fs::remove(socket_);
  pid_ = spawn_logged({"redis-server", "--port", "0", "--unixsocket", socket_.string(), "--save", "", "--appendonly", "no",
                "--maxmemory-policy", "noeviction", "--dir", dir_.string()},
               dir_ / "redis.log");
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
                             std::vector<std::string> extra)
    : url_(std::move(url)), name_(std::move(name)), log_(log_dir / (name_ + ".log")), threads_(threads),
      extra_(std::move(extra)) {
  start();
}
WorkerProcess::~WorkerProcess() { reap(pid_, SIGKILL); }

void WorkerProcess::start() {
  std::vector<std::string> args = {TALLY_WORKER_BIN, "--redis", url_, "--name", name_, "--threads",
                                   std::to_string(threads_)};
  args.insert(args.end(), extra_.begin(), extra_.end());
  pid_ = spawn_logged(args, log_);
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
