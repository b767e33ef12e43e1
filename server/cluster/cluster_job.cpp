#include "server/cluster/cluster_job.hpp"

#include <fmt/format.h>

#include "server/cluster/cluster_store.hpp"
#include "server/cluster/result_key.hpp"

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

std::string ClusterJob::read_results(RedisConn& conn, ClusterPassRun& pr, bool prefetch, size_t& bytes,
                                     std::string_view key) {
  const PassWork& pass = pr.work;
  const EntryPlan& plan = pr.plan;
  const size_t ng = pass.groups.size();
  if (pr.got.size() != ng) {
    pr.got.assign(ng, std::nullopt);
    pr.got_count = 0;
  }
  const PassKeys keys(ej.id, run, pass.pass);
  // Read already: decoded and waiting, or handed to the manager (streamed).
  const auto read = [&](size_t group) { return group < pr.delivered || pr.got[group].has_value(); };
  std::vector<size_t> want;  // indices into plan.entries
  if (prefetch) {
    for (const std::string& k : stored_entry_slots(conn, keys)) {
      size_t first = 0;
      try {
        first = std::stoull(k);
      } catch (const std::exception&) {
        return "a result field is not a slot number";
      }
      const size_t e = plan.entry_at(first);
      if (e == EntryPlan::npos) return fmt::format("result field {} is not the first slot of an entry of the pass", first);
      if (!read(plan.entry_groups[e])) want.push_back(e);
    }
  } else {
    for (size_t e = 0; e < plan.entries.size(); ++e) {
      if (!read(plan.entry_groups[e])) want.push_back(e);
    }
  }
  if (want.empty()) return {};
  std::vector<size_t> firsts;
  for (size_t e : want) firsts.push_back(plan.entries[e].first);
  const std::vector<StoredEntry> values = read_entry_values(conn, keys, firsts);
  for (size_t i = 0; i < want.size(); ++i) {
    const std::optional<std::string>& v = values[i].results;
    if (!v) continue;
    // Results changed in Redis fail the job instead of merging other bits.
    const std::string slot = std::to_string(firsts[i]);
    std::string error = check_entry_digest(key, ej.id, run, pass.pass, slot, *v, values[i].digest);
    if (!error.empty()) return error;
    std::vector<BlockResult> res;
    if (error = decode_entry(pass, plan, want[i], *v, res); !error.empty()) return error;
    bytes += v->size();
    pr.bytes_read += v->size();
    const size_t g0 = plan.entry_groups[want[i]];
    for (size_t j = 0; j < res.size(); ++j) pr.got[g0 + j] = std::move(res[j]);
    pr.got_count += res.size();
  }
  return {};
}


}  // namespace tally::cluster
