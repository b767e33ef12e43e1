#pragma once
// How many worker threads this process should run: the CPUs it may use
// (affinity) capped by a cgroup CPU quota (containers: docker --cpus, k8s limits),
// read by the host's one rule (server/host/host_facts.hpp).
#include "server/host/host_facts.hpp"

namespace tally {

unsigned default_worker_count();

}  // namespace tally
