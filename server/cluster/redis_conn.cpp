#include "server/cluster/redis_conn.hpp"

#include <hiredis/hiredis.h>
#include <fmt/format.h>

#include <charconv>

namespace tally::cluster {

namespace {

RValue convert(const redisReply* r) {
  RValue v;
  switch (r->type) {
    case REDIS_REPLY_STRING:
      v.type = RValue::Type::string;
      v.str.assign(r->str, r->len);
      break;
    case REDIS_REPLY_STATUS:
      v.type = RValue::Type::status;
      v.str.assign(r->str, r->len);
      break;
    case REDIS_REPLY_ERROR:
      v.type = RValue::Type::error;
      v.str.assign(r->str, r->len);
      break;
    case REDIS_REPLY_INTEGER:
      v.type = RValue::Type::integer;
      v.integer = r->integer;
      break;
    case REDIS_REPLY_ARRAY:
      v.type = RValue::Type::array;
      v.elems.reserve(r->elements);
      for (size_t i = 0; i < r->elements; ++i) v.elems.push_back(convert(r->element[i]));
      break;
    default:
      v.type = RValue::Type::nil;
  }
  return v;
}

int parse_int(std::string_view s, std::string_view what) {
  int v = 0;
  auto [p, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
  if (ec != std::errc() || p != s.data() + s.size()) {
    throw std::invalid_argument(fmt::format("redis URL: {} must be an integer, got \"{}\"", what, s));
  }
  return v;
}

}  // namespace

long long RValue::as_int() const {
  if (type == Type::integer) return integer;
  if (type == Type::nil) return 0;
  if (type == Type::string || type == Type::status) {
    long long v = 0;
    auto [p, ec] = std::from_chars(str.data(), str.data() + str.size(), v);
    if (ec == std::errc() && p == str.data() + str.size()) return v;
  }
  throw RedisReplyError(fmt::format("expected an integer reply, got \"{}\"", str));
}

std::optional<long long> RValue::to_int() const noexcept {
  if (type == Type::integer) return integer;
  if (type == Type::string || type == Type::status) {
    long long v = 0;
    auto [p, ec] = std::from_chars(str.data(), str.data() + str.size(), v);
    if (ec == std::errc() && p == str.data() + str.size()) return v;
  }
  return std::nullopt;
}

std::string RedisUrl::display() const {
  if (!unix_path.empty()) return "unix://" + (user.empty() ? std::string() : user + "@") + unix_path;
  return fmt::format("redis://{}{}:{}/{}", user.empty() ? "" : user + "@", host, port, db);
}

namespace {

// The credentials of a URL: "user:password", or "password" alone for the default user
// (redis://secret@host).
void set_credentials(RedisUrl& u, std::string_view cred) {
  if (auto colon = cred.find(':'); colon != std::string_view::npos) {
    u.user = std::string(cred.substr(0, colon));
    u.password = std::string(cred.substr(colon + 1));
  } else {
    u.password = std::string(cred);
  }
}

}  // namespace

RedisUrl parse_redis_url(std::string_view url) {
  RedisUrl u;
  if (url.starts_with("unix://")) {
    std::string_view rest = url.substr(7);
    // unix://[[user]:password@]/path: credentials before the absolute path.
    if (auto at = rest.find("@/"); at != std::string_view::npos) {
      set_credentials(u, rest.substr(0, at));
      rest = rest.substr(at + 1);
    }
    if (auto q = rest.find("?db="); q != std::string_view::npos) {
      u.db = parse_int(rest.substr(q + 4), "db");
      rest = rest.substr(0, q);
    }
    if (rest.empty() || rest.front() != '/') {
      throw std::invalid_argument("redis URL: unix:// needs an absolute socket path, e.g. unix:///run/redis.sock");
    }
    u.unix_path = std::string(rest);
    return u;
  }
  if (!url.starts_with("redis://")) {
    throw std::invalid_argument(fmt::format(
        "redis URL must start with redis:// or unix:// (rediss:// TLS is not supported by hiredis 0.14), got \"{}\"",
        url));
  }
  std::string_view rest = url.substr(8);
  if (auto at = rest.rfind('@'); at != std::string_view::npos) {
    set_credentials(u, rest.substr(0, at));
    rest = rest.substr(at + 1);
  }
  if (auto slash = rest.find('/'); slash != std::string_view::npos) {
    std::string_view db = rest.substr(slash + 1);
    if (!db.empty()) u.db = parse_int(db, "db");
    rest = rest.substr(0, slash);
  }
  if (auto colon = rest.rfind(':'); colon != std::string_view::npos) {
    u.port = parse_int(rest.substr(colon + 1), "port");
    rest = rest.substr(0, colon);
  }
  if (rest.empty()) throw std::invalid_argument("redis URL: the host is missing");
  u.host = std::string(rest);
  if (u.port <= 0 || u.port > 65535) throw std::invalid_argument("redis URL: port out of range");
  return u;
}

RedisConn::RedisConn(const RedisUrl& url, std::chrono::milliseconds timeout) {
  timeval tv{};
  tv.tv_sec = static_cast<time_t>(timeout.count() / 1000);
  tv.tv_usec = static_cast<suseconds_t>((timeout.count() % 1000) * 1000);
  ctx_ = url.unix_path.empty() ? redisConnectWithTimeout(url.host.c_str(), url.port, tv)
                               : redisConnectUnixWithTimeout(url.unix_path.c_str(), tv);
  if (!ctx_) throw RedisIoError("cannot allocate a redis context");
  if (ctx_->err) {
    const std::string msg = fmt::format("cannot connect to {}: {}", url.display(), ctx_->errstr);
    redisFree(ctx_);
    ctx_ = nullptr;
    throw RedisIoError(msg);
  }
  redisSetTimeout(ctx_, tv);
  try {
    if (!url.password.empty()) {
      if (url.user.empty()) {
        cmd({"AUTH", url.password});
      } else {
        cmd({"AUTH", url.user, url.password});
      }
    } else {
      cmd({"PING"});  // NOAUTH here, not on some later command
    }
  } catch (const RedisReplyError& e) {
    redisFree(ctx_);
    ctx_ = nullptr;
    throw RedisAuthError(fmt::format("redis at {} refused the credentials{}: {}", url.display(),
                                     url.password.empty() ? " (the URL has no password)" : "", e.what()));
  } catch (...) {
    redisFree(ctx_);
    ctx_ = nullptr;
    throw;
  }
  try {
    if (url.db != 0) cmd({"SELECT", std::to_string(url.db)});
  } catch (const RedisReplyError& e) {
    redisFree(ctx_);
    ctx_ = nullptr;
    throw RedisAuthError(fmt::format("redis at {}: SELECT {}: {}", url.display(), url.db, e.what()));
  } catch (...) {
    redisFree(ctx_);
    ctx_ = nullptr;
    throw;
  }
}

RedisConn::~RedisConn() {
  if (ctx_) redisFree(ctx_);
}

void RedisConn::append(const std::vector<std::string_view>& argv) {
  std::vector<const char*> ptrs;
  std::vector<size_t> lens;
  ptrs.reserve(argv.size());
  lens.reserve(argv.size());
  for (auto a : argv) {
    ptrs.push_back(a.data());
    lens.push_back(a.size());
  }
  if (redisAppendCommandArgv(ctx_, static_cast<int>(argv.size()), ptrs.data(), lens.data()) != REDIS_OK) {
    throw RedisIoError(fmt::format("redis: {}", ctx_->errstr));
  }
}

RValue RedisConn::get_reply() {
  void* raw = nullptr;
  if (redisGetReply(ctx_, &raw) != REDIS_OK || !raw) {
    throw RedisIoError(fmt::format("redis: {}", ctx_->errstr[0] ? ctx_->errstr : "connection lost"));
  }
  auto* r = static_cast<redisReply*>(raw);
  RValue v = convert(r);
  freeReplyObject(r);
  return v;
}

RValue RedisConn::cmd(const std::vector<std::string_view>& argv) {
  append(argv);
  RValue v = get_reply();
  if (v.type == RValue::Type::error) throw RedisReplyError(v.str);
  return v;
}

std::string RedisConn::load_script(std::string_view source) { return cmd({"SCRIPT", "LOAD", source}).str; }

RValue RedisConn::evalsha(const std::string& sha, std::string_view source, const std::vector<std::string_view>& keys,
                          const std::vector<std::string_view>& args) {
  const std::string nkeys = std::to_string(keys.size());
  std::vector<std::string_view> argv = {"EVALSHA", sha, nkeys};
  argv.insert(argv.end(), keys.begin(), keys.end());
  argv.insert(argv.end(), args.begin(), args.end());
  try {
    return cmd(argv);
  } catch (const RedisReplyError& e) {
    if (std::string_view(e.what()).find("NOSCRIPT") == std::string_view::npos) throw;
    load_script(source);  // Redis restarted and forgot it: same source, same SHA1
    return cmd(argv);
  }
}

std::string RedisConn::run_id() {
  const RValue info = cmd({"INFO", "server"});
  const std::string_view s = info.str;
  const size_t p = s.find("run_id:");
  if (p == std::string_view::npos) return {};
  const size_t e = s.find_first_of("\r\n", p);
  return std::string(s.substr(p + 7, e == std::string_view::npos ? std::string_view::npos : e - p - 7));
}

}  // namespace tally::cluster
