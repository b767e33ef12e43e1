#pragma once
// The one logging facade: levels, `job=<id>` on every job line, text or JSON
// lines on stderr. spdlog (Debian libspdlog-dev) does the writing; it is
// included only in log.cpp, so callers see fmt-style calls and nothing else.
// Thread-safe. Not for hot loops: log at pass boundaries and lifecycle changes.
#include <fmt/format.h>

#include <optional>
#include <string>
#include <string_view>

namespace tally::log {

enum class Level { debug, info, warn, error, off };
enum class Format { text, json };

std::optional<Level> parse_level(std::string_view name);    // debug|info|warn|error|off
std::optional<Format> parse_format(std::string_view name);  // text|json

// Call once at start-up (default: info, text).
void configure(Level level, Format format);
bool enabled(Level level);

// One line. `job` empty: a server line; else the line carries job=<id>.
void write(Level level, std::string_view job, std::string_view message);

template <typename... A>
void info(fmt::format_string<A...> f, A&&... a) {
  if (enabled(Level::info)) write(Level::info, {}, fmt::format(f, std::forward<A>(a)...));
}
template <typename... A>
void warn(fmt::format_string<A...> f, A&&... a) {
  if (enabled(Level::warn)) write(Level::warn, {}, fmt::format(f, std::forward<A>(a)...));
}
template <typename... A>
void error(fmt::format_string<A...> f, A&&... a) {
  if (enabled(Level::error)) write(Level::error, {}, fmt::format(f, std::forward<A>(a)...));
}
// Lines about one job.
template <typename... A>
void job(Level level, std::string_view id, fmt::format_string<A...> f, A&&... a) {
  if (enabled(level)) write(level, id, fmt::format(f, std::forward<A>(a)...));
}

}  // namespace tally::log
