#pragma once
// A small synchronous wrapper over hiredis 0.14 (RESP2, no TLS): one RedisConn per
// thread (a redisContext is not thread-safe). Commands go through redisCommandArgv,
// binary-safe, never printf-style formatting. Replies are copied into RValue so no
// hiredis type leaks out of this file.
#include <chrono>
#include <optional>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

struct redisContext;

namespace tally::cluster {

// redis://[[user]:password@]host[:port][/db]  or  unix://[[user]:password@]/path/to.sock[?db=N]
struct RedisUrl {
  std::string host;
  int port = 6379;
  std::string unix_path;  // set for unix://
  std::string user;       // ACL user ("" = default user)
  std::string password;
  int db = 0;
  std::string display() const;  // without the password, for logs and /readyz
};
// Throws std::invalid_argument naming what is wrong.
RedisUrl parse_redis_url(std::string_view url);

// Thrown when the connection is lost or cannot be made: the caller reconnects later.
class RedisIoError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};
// Redis refused the connection's set-up: the credentials (WRONGPASS; NOAUTH: a password
// is required; an ACL user that may not connect) or the database (SELECT). A
// configuration error, not an outage: processes report it at start instead of
// retrying forever.
class RedisAuthError : public RedisIoError {
 public:
  using RedisIoError::RedisIoError;
};
// An error reply (e.g. NOGROUP, WRONGTYPE, NOSCRIPT): the connection is still fine.
class RedisReplyError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct RValue {
  enum class Type { nil, string, integer, array, status, error } type = Type::nil;
  std::string str;  // string, status and error replies
  long long integer = 0;
  std::vector<RValue> elems;

  bool is_nil() const { return type == Type::nil; }
  bool is_array() const { return type == Type::array; }
  // A string or integer reply as an integer (0 for nil); throws on other types.
  long long as_int() const;
  // The same without throwing: nullopt for anything that is not an integer.
  std::optional<long long> to_int() const noexcept;
};

class RedisConn {
 public:
  // Connects, authenticates (a PING without a password, so a server that requires one
  // says so here) and selects the database; throws RedisAuthError when the
  // credentials are refused, RedisIoError when Redis cannot be reached.
  // `timeout`: connect timeout and socket read/write timeout (blocking commands
  // must use a shorter BLOCK/timeout than this).
  RedisConn(const RedisUrl& url, std::chrono::milliseconds timeout = std::chrono::milliseconds(5000));
  ~RedisConn();
  RedisConn(const RedisConn&) = delete;
  RedisConn& operator=(const RedisConn&) = delete;

  // One command; throws RedisIoError (connection unusable afterwards) or
  // RedisReplyError (an error reply).
  RValue cmd(const std::vector<std::string_view>& argv);
  // Pipelining: queue commands, then read their replies in order. get_reply returns
  // error replies as RValue::Type::error instead of throwing.
  void append(const std::vector<std::string_view>& argv);
  RValue get_reply();

  // Loads a Lua script and returns its SHA1 for evalsha().
  std::string load_script(std::string_view source);
  // EVALSHA, reloading the script once if Redis lost it (restart).
  RValue evalsha(const std::string& sha, std::string_view source, const std::vector<std::string_view>& keys,
                 const std::vector<std::string_view>& args);

  // `run_id` of the Redis process (changes when Redis restarts).
  std::string run_id();

 private:
  redisContext* ctx_ = nullptr;
};

}  // namespace tally::cluster
