// server/host/host_facts: RSS, MemTotal and the cgroup limits read from a fake host
// tree, and the one cgroup rule (own cgroup, then the root; v2, then v1) giving the
// CPU quota and the memory limit from the same directory.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <string>
#include <unistd.h>

#include "server/executor/cpu_quota.hpp"
#include "server/host/host_facts.hpp"

namespace tally {
namespace {

namespace fs = std::filesystem;

class FakeHost {
 public:
  FakeHost() : dir_(fs::temp_directory_path() / ("tally_host_" + std::to_string(::getpid()) + "_" + std::to_string(next_++))) {
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  ~FakeHost() {
    std::error_code ec;
    fs::remove_all(dir_, ec);
  }
  void put(const std::string& rel, const std::string& text) const {
    const fs::path p = dir_ / rel;
    fs::create_directories(p.parent_path());
    std::ofstream(p) << text;
  }
  HostRoot root() const { return HostRoot{dir_}; }

 private:
  static inline int next_ = 0;
  fs::path dir_;
};

TEST(HostFacts, ResidentAndTotalMemoryFromProc) {
  FakeHost h;
  EXPECT_FALSE(resident_bytes(h.root()));
  EXPECT_FALSE(memory_total(h.root()));
  h.put("proc/self/status", "Name:\ttally\nVmRSSx:\t1 kB\nVmRSS:\t    2048 kB\nVmHWM:\t4096 kB\n");
  h.put("proc/meminfo", "MemFree:  1 kB\nMemTotal:       16777216 kB\n");
  EXPECT_EQ(resident_bytes(h.root()), 2048u * 1024);
  EXPECT_EQ(memory_total(h.root()), 16777216ull * 1024);
}

// cgroup v2: the process's own cgroup decides for both controllers, over the root's.
TEST(HostFacts, CgroupV2OwnCgroupFirstForCpuAndMemory) {
  FakeHost h;
  h.put("proc/self/cgroup", "0::/jobs.slice/tally\n");
  h.put("sys/fs/cgroup/cpu.max", "max 100000\n");
  h.put("sys/fs/cgroup/memory.max", "max\n");
  h.put("sys/fs/cgroup/jobs.slice/tally/cpu.max", "150000 100000\n");
  h.put("sys/fs/cgroup/jobs.slice/tally/memory.max", "1073741824\n");
  EXPECT_DOUBLE_EQ(cgroup_cpu_quota(h.root()).value(), 1.5);
  EXPECT_EQ(cgroup_memory_limit(h.root()), 1073741824u);
}

// The own cgroup has no such file (a container sees its cgroup at the root): the
// root's file decides, and "max" there means no limit.
TEST(HostFacts, CgroupV2FallsBackToTheRoot) {
  FakeHost h;
  h.put("proc/self/cgroup", "0::/elsewhere\n");
  h.put("sys/fs/cgroup/cpu.max", "200000 100000\n");
  h.put("sys/fs/cgroup/memory.max", "max\n");
  EXPECT_DOUBLE_EQ(cgroup_cpu_quota(h.root()).value(), 2.0);
  EXPECT_FALSE(cgroup_memory_limit(h.root()));
}

// cgroup v1: each controller's own path within its mount; controller lists match by
// whole name ("cpuset" is not "cpu").
TEST(HostFacts, CgroupV1ControllersByWholeName) {
  FakeHost h;
  h.put("proc/self/cgroup", "5:cpuset:/wrong\n4:memory:/m\n3:cpu,cpuacct:/c\n");
  h.put("sys/fs/cgroup/cpu,cpuacct/wrong/cpu.cfs_quota_us", "900000\n");
  h.put("sys/fs/cgroup/cpu,cpuacct/wrong/cpu.cfs_period_us", "100000\n");
  h.put("sys/fs/cgroup/cpu,cpuacct/c/cpu.cfs_quota_us", "50000\n");
  h.put("sys/fs/cgroup/cpu,cpuacct/c/cpu.cfs_period_us", "100000\n");
  h.put("sys/fs/cgroup/cpu,cpuacct/cpu.cfs_quota_us", "-1\n");
  h.put("sys/fs/cgroup/cpu,cpuacct/cpu.cfs_period_us", "100000\n");
  h.put("sys/fs/cgroup/memory/memory.limit_in_bytes", "9223372036854771712\n");
  h.put("sys/fs/cgroup/memory/m/memory.limit_in_bytes", "536870912\n");
  EXPECT_DOUBLE_EQ(cgroup_cpu_quota(h.root()).value(), 0.5);
  EXPECT_EQ(cgroup_memory_limit(h.root()), 536870912u);
  // Without the own cgroup's files, the mount's root: -1 is "no quota".
  h.put("proc/self/cgroup", "4:memory:/gone\n3:cpu,cpuacct:/gone\n");
  EXPECT_FALSE(cgroup_cpu_quota(h.root()));
  EXPECT_EQ(cgroup_memory_limit(h.root()), 9223372036854771712u);
}

TEST(HostFacts, NoCgroupNoLimits) {
  FakeHost h;
  EXPECT_FALSE(cgroup_cpu_quota(h.root()));
  EXPECT_FALSE(cgroup_memory_limit(h.root()));
}

TEST(HostFacts, ParseCpuMax) {
  EXPECT_DOUBLE_EQ(parse_cgroup_cpu_max("200000 100000\n").value(), 2.0);
  EXPECT_DOUBLE_EQ(parse_cgroup_cpu_max("150000").value(), 1.5);
  EXPECT_FALSE(parse_cgroup_cpu_max("max 100000\n"));
  EXPECT_FALSE(parse_cgroup_cpu_max("0 100000"));
  EXPECT_FALSE(parse_cgroup_cpu_max("garbage"));
}

// On this (Linux) host: the real files are read.
TEST(HostFacts, RealHost) {
  EXPECT_GT(resident_bytes().value(), 1u << 20);
  EXPECT_GT(memory_total().value(), resident_bytes().value());
  EXPECT_GE(default_worker_count(), 1u);
}

}  // namespace
}  // namespace tally
