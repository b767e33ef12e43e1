#pragma once
// What the host grants this process, read in one place by one rule: resident memory
// (GET /metrics), the machine's memory and the cgroup memory limit (the default
// memory budget, server/host/memory_budget.cpp), the cgroup CPU quota (the default
// worker count, server/executor/cpu_quota.cpp).
//
// The cgroup rule, the same for every controller: the process's own cgroup (from
// /proc/self/cgroup) first, then the root of the hierarchy (a container's namespace
// root); cgroup v2 (the unified hierarchy) before v1 (the controller's own mount). The
// first directory that has the controller's file decides, also when it says "no
// limit". Every reader takes the root it reads under ("/" on a real host; a directory
// laid out the same way in tests).
#include <cstdint>
#include <filesystem>
#include <optional>
#include <string_view>

namespace tally {

struct HostRoot {
  std::filesystem::path dir = "/";
};

// VmRSS of /proc/self/status in bytes; nullopt off Linux.
std::optional<uint64_t> resident_bytes(const HostRoot& root = {});
// MemTotal of /proc/meminfo in bytes.
std::optional<uint64_t> memory_total(const HostRoot& root = {});
// The cgroup memory limit in bytes (v2 memory.max, v1 memory.limit_in_bytes); nullopt
// when there is none ("max"). cgroup v1 says "no limit" with a huge number: callers
// take the smaller of this and memory_total().
std::optional<uint64_t> cgroup_memory_limit(const HostRoot& root = {});
// The CPU quota in CPUs (v2 cpu.max, v1 cpu.cfs_quota_us / cpu.cfs_period_us); nullopt
// when there is none.
std::optional<double> cgroup_cpu_quota(const HostRoot& root = {});

// "200000 100000" -> 2.0; "max 100000" -> nullopt (cgroup v2 cpu.max).
std::optional<double> parse_cgroup_cpu_max(std::string_view text);

}  // namespace tally
