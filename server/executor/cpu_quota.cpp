#include "server/executor/cpu_quota.hpp"

#include <algorithm>
#include <cmath>

#include "common/engine/pass_loop.hpp"

namespace tally {

unsigned default_worker_count() {
  unsigned n = available_cpus();
  if (const auto q = cgroup_cpu_quota()) n = std::min(n, static_cast<unsigned>(std::max(1.0, std::ceil(*q))));
  return std::max(1u, n);
}

}  // namespace tally
