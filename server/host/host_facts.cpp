#include "server/host/host_facts.hpp"

#include <algorithm>
#include <charconv>
#include <fstream>
#include <initializer_list>
#include <sstream>
#include <string>
#include <vector>

namespace tally {

namespace fs = std::filesystem;

namespace {

std::optional<std::string> read_file(const fs::path& path) {
  std::ifstream in(path);
  if (!in) return std::nullopt;
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

std::string_view trim(std::string_view s) {
  while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) s.remove_prefix(1);
  while (!s.empty() && (s.back() == '\n' || s.back() == ' ' || s.back() == '\t')) s.remove_suffix(1);
  return s;
}

template <class T>
std::optional<T> parse_number(std::string_view s) {
  s = trim(s);
  T v{};
  const auto [p, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
  if (ec != std::errc() || p != s.data() + s.size()) return std::nullopt;
  return v;
}

// "<Name>: <n> kB" of a /proc file, in bytes.
std::optional<uint64_t> proc_kib_field(const fs::path& path, std::string_view name) {
  const auto text = read_file(path);
  if (!text) return std::nullopt;
  std::istringstream in(*text);
  for (std::string line; std::getline(in, line);) {
    if (line.size() > name.size() && line.compare(0, name.size(), name) == 0 && line[name.size()] == ':') {
      std::istringstream f(line.substr(name.size() + 1));
      uint64_t kib = 0;
      if (f >> kib) return kib * 1024;
    }
  }
  return std::nullopt;
}

fs::path under(const HostRoot& root, std::string_view abs) { return root.dir / fs::path(abs).relative_path(); }

// This process's cgroup path for a v1 `controller`, or for v2 when it is ""
// (/proc/self/cgroup lines are "hierarchy-ID:controller-list:path"); "" if unknown.
std::string own_cgroup(const HostRoot& root, std::string_view controller) {
  const auto text = read_file(under(root, "/proc/self/cgroup"));
  if (!text) return {};
  std::istringstream in(*text);
  for (std::string line; std::getline(in, line);) {
    const size_t a = line.find(':');
    const size_t b = a == std::string::npos ? a : line.find(':', a + 1);
    if (b == std::string::npos) continue;
    const std::string_view list = std::string_view(line).substr(a + 1, b - a - 1);
    bool match = controller.empty() && list.empty();
    if (!controller.empty()) {
      // The list is comma-separated ("cpu,cpuacct"): match whole names only.
      for (size_t start = 0; start <= list.size();) {
        const size_t comma = std::min(list.find(',', start), list.size());
        if (list.substr(start, comma - start) == controller) match = true;
        start = comma + 1;
      }
    }
    if (match) return line.substr(b + 1);
  }
  return {};
}

// The rule (host_facts.hpp): the first directory holding `file`, trying for v2 the
// own cgroup then the root of /sys/fs/cgroup, then for v1 each mount of `controller`
// (own cgroup, then that mount's root).
std::optional<fs::path> cgroup_dir(const HostRoot& root, std::string_view file, std::string_view controller,
                                   std::initializer_list<std::string_view> v1_mounts) {
  const fs::path base = under(root, "/sys/fs/cgroup");
  std::vector<fs::path> dirs;
  const auto own_then_root = [&](const fs::path& mount, const std::string& own) {
    const fs::path rel = fs::path(own).relative_path();
    if (!rel.empty()) dirs.push_back(mount / rel);
    dirs.push_back(mount);
  };
  own_then_root(base, own_cgroup(root, ""));
  const std::string own_v1 = own_cgroup(root, controller);
  for (std::string_view mount : v1_mounts) own_then_root(base / mount, own_v1);
  for (const fs::path& dir : dirs) {
    if (fs::is_regular_file(dir / file)) return dir;
  }
  return std::nullopt;
}

}  // namespace

std::optional<uint64_t> resident_bytes(const HostRoot& root) {
  return proc_kib_field(under(root, "/proc/self/status"), "VmRSS");
}

std::optional<uint64_t> memory_total(const HostRoot& root) {
  return proc_kib_field(under(root, "/proc/meminfo"), "MemTotal");
}

std::optional<uint64_t> cgroup_memory_limit(const HostRoot& root) {
  if (const auto dir = cgroup_dir(root, "memory.max", "memory", {})) {
    const auto text = read_file(*dir / "memory.max");
    return text ? parse_number<uint64_t>(*text) : std::nullopt;  // "max": no limit
  }
  if (const auto dir = cgroup_dir(root, "memory.limit_in_bytes", "memory", {"memory"})) {
    const auto text = read_file(*dir / "memory.limit_in_bytes");
    return text ? parse_number<uint64_t>(*text) : std::nullopt;
  }
  return std::nullopt;
}

std::optional<double> parse_cgroup_cpu_max(std::string_view text) {
  text = trim(text);
  const size_t sp = text.find(' ');
  const std::string_view quota = text.substr(0, sp);
  if (quota == "max" || quota.empty()) return std::nullopt;
  const auto q = parse_number<double>(quota);
  const auto p = sp == std::string_view::npos ? std::optional<double>(100000.0) : parse_number<double>(text.substr(sp + 1));
  if (!q || !p || *q <= 0 || *p <= 0) return std::nullopt;
  return *q / *p;
}

std::optional<double> cgroup_cpu_quota(const HostRoot& root) {
  if (const auto dir = cgroup_dir(root, "cpu.max", "cpu", {})) {
    const auto text = read_file(*dir / "cpu.max");
    return text ? parse_cgroup_cpu_max(*text) : std::nullopt;
  }
  if (const auto dir = cgroup_dir(root, "cpu.cfs_quota_us", "cpu", {"cpu,cpuacct", "cpu"})) {
    const auto q = read_file(*dir / "cpu.cfs_quota_us");
    const auto p = read_file(*dir / "cpu.cfs_period_us");
    const auto qv = q ? parse_number<double>(*q) : std::nullopt;
    const auto pv = p ? parse_number<double>(*p) : std::nullopt;
    if (!qv || !pv || *qv <= 0 || *pv <= 0) return std::nullopt;  // -1: no quota
    return *qv / *pv;
  }
  return std::nullopt;
}

}  // namespace tally
