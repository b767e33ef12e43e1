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
  explicit RedisServer(std::filesystem::path dir);
  ~RedisServer();
  void start();
  void stop();  // SIGKILL: everything in it is lost (no persistence)
  std::string url() const { return "unix://" + socket_.string(); }
  cluster::RedisConn connect() const;

 private:
  std::filesystem::path dir_, socket_;
  pid_t pid_ = -1;
};

class WorkerProcess {
 public:
  WorkerProcess(std::string url, std::string name, std::filesystem::path log_dir, unsigned threads = 1,
                std::vector<std::string> extra = {});
  ~WorkerProcess();
  void start();
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
  pid_t pid_ = -1;
};

}  // namespace tally::e2e
