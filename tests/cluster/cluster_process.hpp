#pragma once
// Processes of a cluster test: a private redis-server on a Unix socket in a temp dir
// (no TCP port, no persistence) and tally-worker processes. Every wait is bounded.
#include <signal.h>
#include <sys/types.h>

#include <filesystem>
#include <string>
#include <vector>

#include "server/cluster/redis_conn.hpp"

namespace tally::e2e {

class RedisServer {
 public:
  // `extra`: more redis-server arguments (e.g. --requirepass, --user ...);
  // `credentials`: "user:password" or "password" put into url(), "" for none;
  // `tcp_port` > 0: also listen on 127.0.0.1:tcp_port.
  explicit RedisServer(std::filesystem::path dir, std::vector<std::string> extra = {}, std::string credentials = {},
                       int tcp_port = 0);
  ~RedisServer();
  void start();
  void stop();  // SIGKILL: everything in it is lost (no persistence)
  std::string url() const {
    return "unix://" + (credentials_.empty() ? std::string() : credentials_ + "@") + socket_.string();
  }
  std::string socket() const { return socket_.string(); }
  cluster::RedisConn connect() const;

 private:
  std::filesystem::path dir_, socket_;
  std::vector<std::string> extra_;
  std::string credentials_;
  int tcp_port_ = 0;
  pid_t pid_ = -1;
};

// A free TCP port on 127.0.0.1 (bound, read, closed: a small race, fine for tests).
int free_loopback_port();

// Which worker binary and environment a WorkerProcess runs.
struct WorkerOptions {
  std::string bin;                // default: tally-worker
  std::vector<std::string> env;   // NAME=value, e.g. TALLY_TEST_FAULT=... for tally-test-worker
  bool test_worker = false;       // true: tally-test-worker (fault injection, tests only)
};

class WorkerProcess {
 public:
  WorkerProcess(std::string url, std::string name, std::filesystem::path log_dir, unsigned threads = 1,
                std::vector<std::string> extra = {}, WorkerOptions options = {});
  ~WorkerProcess();
  void start();
  // True once the process has ended (reaped); exit_code() then says how (128+signal).
  bool exited();
  int exit_code() const { return exit_code_; }
  void kill9();
  void pause();   // SIGSTOP
  void resume();  // SIGCONT
  int terminate();
  std::string log() const;
  const std::string& name() const { return name_; }

 private:
  std::string url_, name_;
  std::filesystem::path log_;
  unsigned threads_;
  std::vector<std::string> extra_;
  WorkerOptions options_;
  pid_t pid_ = -1;
  int exit_code_ = -1;
};

}  // namespace tally::e2e
