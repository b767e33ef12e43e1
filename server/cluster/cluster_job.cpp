#include "server/cluster/cluster_job.hpp"

namespace tally::cluster {

std::vector<PassKeys> ClusterJob::passes_out() const {
  std::vector<PassKeys> passes = {PassKeys(ej.id, run, cur.work.pass)};
  if (ahead) passes.emplace_back(ej.id, run, ahead->work.pass);
  return passes;
}

std::vector<PassKeys> ClusterJob::digest_keys() const {
  std::vector<PassKeys> keys;
  for (uint64_t p : digest_passes) keys.emplace_back(ej.id, run, p);
  return keys;
}

std::vector<PassKeys> ClusterJob::retire_current(size_t keep) {
  digest_passes.push_back(cur.work.pass);
  std::vector<PassKeys> old;
  while (digest_passes.size() > keep) {
    old.emplace_back(ej.id, run, digest_passes.front());
    digest_passes.pop_front();
  }
  return old;
}

}  // namespace tally::cluster
