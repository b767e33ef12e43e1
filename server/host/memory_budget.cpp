#include "server/host/memory_budget.hpp"

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>
#include <string>

#include "server/host/host_facts.hpp"

namespace tally {

namespace {

// Splits "12.5GiB" into 12.5 and "GiB".
bool split_number(std::string_view s, double& value, std::string_view& unit) {
  size_t i = 0;
  while (i < s.size() && (std::isdigit(static_cast<unsigned char>(s[i])) || s[i] == '.')) ++i;
  if (i == 0) return false;
  const std::string num(s.substr(0, i));
  const auto [p, ec] = std::from_chars(num.data(), num.data() + num.size(), value);
  if (ec != std::errc() || p != num.data() + num.size() || !std::isfinite(value) || value < 0) return false;
  unit = s.substr(i);
  while (!unit.empty() && unit.front() == ' ') unit.remove_prefix(1);
  return true;
}

}  // namespace

uint64_t default_memory_budget() {
  // The host's facts by their one rule (server/host/host_facts.hpp). cgroup v1 reports
  // "no limit" as a huge number; min() takes care of it.
  std::optional<uint64_t> limit = memory_total();
  if (const auto v = cgroup_memory_limit()) limit = limit ? std::min(*limit, *v) : *v;
  return limit ? *limit / 2 : 0;
}

std::optional<uint64_t> parse_byte_size(std::string_view s) {
  double v = 0;
  std::string_view unit;
  if (!split_number(s, v, unit)) return std::nullopt;
  double mult = 0;
  struct U {
    std::string_view name;
    double mult;
  };
  for (const U& u : {U{"", 1}, U{"B", 1}, U{"KiB", 1024.0}, U{"MiB", 1048576.0}, U{"GiB", 1073741824.0},
                     U{"TiB", 1099511627776.0}, U{"KB", 1e3}, U{"MB", 1e6}, U{"GB", 1e9}, U{"TB", 1e12}}) {
    if (unit == u.name) mult = u.mult;
  }
  if (mult == 0 || v * mult >= 1.8e19) return std::nullopt;
  return static_cast<uint64_t>(std::llround(v * mult));
}

std::optional<double> parse_duration_s(std::string_view s) {
  double v = 0;
  std::string_view unit;
  if (!split_number(s, v, unit)) return std::nullopt;
  if (unit.empty() || unit == "s") return v;
  if (unit == "m") return v * 60;
  if (unit == "h") return v * 3600;
  if (unit == "d") return v * 86400;
  return std::nullopt;
}

}  // namespace tally
