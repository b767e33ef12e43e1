#include "common/log/log.hpp"

#include <spdlog/sinks/stdout_sinks.h>
#include <spdlog/spdlog.h>

#include <atomic>
#include <mutex>

namespace tally::log {

namespace {

std::atomic<Level> g_level{Level::info};
std::atomic<Format> g_format{Format::text};

spdlog::level::level_enum to_spdlog(Level l) {
  switch (l) {
    case Level::debug: return spdlog::level::debug;
    case Level::info: return spdlog::level::info;
    case Level::warn: return spdlog::level::warn;
    case Level::error: return spdlog::level::err;
    case Level::off: return spdlog::level::off;
  }
  return spdlog::level::info;
}

std::string json_escape(std::string_view s) {
  std::string out;
  out.reserve(s.size() + 2);
  for (const char ch : s) {
    const auto c = static_cast<unsigned char>(ch);
    switch (c) {
      case '"': out += "\\\""; break;
      case '\\': out += "\\\\"; break;
      case '\n': out += "\\n"; break;
      case '\r': out += "\\r"; break;
      case '\t': out += "\\t"; break;
      default:
        if (c < 0x20) {
          out += fmt::format("\\u{:04x}", c);
        } else {
          out.push_back(ch);
        }
    }
  }
  return out;
}

spdlog::logger& logger() {
  static std::shared_ptr<spdlog::logger> l = [] {
    auto sink = std::make_shared<spdlog::sinks::stderr_sink_mt>();
    auto lg = std::make_shared<spdlog::logger>("tally", sink);
    lg->set_pattern("%Y-%m-%dT%H:%M:%S.%eZ %l %v", spdlog::pattern_time_type::utc);
    lg->set_level(to_spdlog(g_level.load()));
    lg->flush_on(spdlog::level::trace);
    return lg;
  }();
  return *l;
}

}  // namespace

std::optional<Level> parse_level(std::string_view n) {
  if (n == "debug") return Level::debug;
  if (n == "info") return Level::info;
  if (n == "warn" || n == "warning") return Level::warn;
  if (n == "error") return Level::error;
  if (n == "off") return Level::off;
  return std::nullopt;
}

std::optional<Format> parse_format(std::string_view n) {
  if (n == "text") return Format::text;
  if (n == "json") return Format::json;
  return std::nullopt;
}

void configure(Level level, Format format) {
  g_level = level;
  g_format = format;
  spdlog::logger& l = logger();
  l.set_level(to_spdlog(level));
  if (format == Format::json) {
    l.set_pattern(R"({"time":"%Y-%m-%dT%H:%M:%S.%eZ","level":"%l",%v})", spdlog::pattern_time_type::utc);
  } else {
    l.set_pattern("%Y-%m-%dT%H:%M:%S.%eZ %l %v", spdlog::pattern_time_type::utc);
  }
}

bool enabled(Level level) { return level != Level::off && level >= g_level.load(std::memory_order_relaxed); }

void write(Level level, std::string_view job, std::string_view message) {
  std::string line;
  if (g_format.load() == Format::json) {
    if (!job.empty()) line = fmt::format("\"job\":\"{}\",", json_escape(job));
    line += fmt::format("\"msg\":\"{}\"", json_escape(message));
  } else {
    line = job.empty() ? std::string(message) : fmt::format("job={} {}", job, message);
  }
  logger().log(to_spdlog(level), "{}", line);
}

}  // namespace tally::log
