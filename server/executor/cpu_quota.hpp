#pragma once
// How many worker threads this process should run: the CPUs it may use
// (affinity) capped by a cgroup CPU quota (containers: docker --cpus, k8s limits).
#include <optional>
#include <string_view>

namespace tally {

// "200000 100000" -> 2.0; "max 100000" -> nullopt (cgroup v2 cpu.max).
std::optional<double> parse_cgroup_cpu_max(std::string_view text);
// The quota in CPUs from cgroup v2 (cpu.max) or v1 (cfs_quota_us / cfs_period_us).
std::optional<double> cgroup_cpu_quota();
unsigned default_worker_count();

}  // namespace tally
