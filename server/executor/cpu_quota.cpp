#include "server/executor/cpu_quota.hpp"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <fstream>
#include <sstream>
#include <string>

#include "common/engine/local_executor.hpp"

namespace tally {

namespace {

std::optional<std::string> read_file(const std::string& path) {
  std::ifstream in(path);
  if (!in) return std::nullopt;
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

std::optional<double> to_double(std::string_view s) {
  while (!s.empty() && (s.back() == '\n' || s.back() == ' ')) s.remove_suffix(1);
  double v = 0;
  auto [p, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
  if (ec != std::errc() || p != s.data() + s.size()) return std::nullopt;
  return v;
}

// This process's cgroup path for `controller` ("" = the v2 unified hierarchy).
std::string own_cgroup(std::string_view controller) {
  const auto text = read_file("/proc/self/cgroup");
  if (!text) return {};
  std::istringstream in(*text);
  std::string line;
  while (std::getline(in, line)) {
    // hierarchy-ID:controller-list:path
    const size_t a = line.find(':');
    const size_t b = line.find(':', a + 1);
    if (a == std::string::npos || b == std::string::npos) continue;
    const std::string_view list = std::string_view(line).substr(a + 1, b - a - 1);
    if (controller.empty() ? list.empty() : list.find(controller) != std::string_view::npos) return line.substr(b + 1);
  }
  return {};
}

}  // namespace

std::optional<double> parse_cgroup_cpu_max(std::string_view text) {
  while (!text.empty() && (text.back() == '\n' || text.back() == ' ')) text.remove_suffix(1);
  const size_t sp = text.find(' ');
  const std::string_view quota = text.substr(0, sp);
  if (quota == "max" || quota.empty()) return std::nullopt;
  const auto q = to_double(quota);
  const auto p = sp == std::string_view::npos ? std::optional<double>(100000.0) : to_double(text.substr(sp + 1));
  if (!q || !p || *q <= 0 || *p <= 0) return std::nullopt;
  return *q / *p;
}

std::optional<double> cgroup_cpu_quota() {
  // cgroup v2: our own cgroup first, then the root of the namespace (containers).
  for (const std::string& dir : {"/sys/fs/cgroup" + own_cgroup(""), std::string("/sys/fs/cgroup")}) {
    if (auto t = read_file(dir + "/cpu.max")) return parse_cgroup_cpu_max(*t);
  }
  // cgroup v1.
  for (const std::string& base : {std::string("/sys/fs/cgroup/cpu,cpuacct"), std::string("/sys/fs/cgroup/cpu")}) {
    for (const std::string& dir : {base + own_cgroup("cpu"), base}) {
      const auto q = read_file(dir + "/cpu.cfs_quota_us");
      const auto p = read_file(dir + "/cpu.cfs_period_us");
      if (!q || !p) continue;
      const auto qv = to_double(*q), pv = to_double(*p);
      if (!qv || !pv || *qv <= 0 || *pv <= 0) return std::nullopt;  // -1: no quota
      return *qv / *pv;
    }
  }
  return std::nullopt;
}

unsigned default_worker_count() {
  unsigned n = available_cpus();
  if (const auto q = cgroup_cpu_quota()) n = std::min(n, static_cast<unsigned>(std::max(1.0, std::ceil(*q))));
  return std::max(1u, n);
}

}  // namespace tally
