#pragma once
// Decoded states of finished jobs, read back from the store for their image routes and
// kept in memory, most recently used first, up to a byte capacity. A state larger than
// the whole capacity (a 4K frame's 0.8 GB against the default 256 MiB) is kept too, alone
// beside the others, until it has not been read for `oversize_idle_s` or another such
// state replaces it: the reads of one finished frame come in runs (a tev bridge's or a
// page's tiles, a PNG refresh) and each used to decode the whole checkpoint again.
// Thread-safe (its own lock, never held while the store is read).
#include <chrono>
#include <cstdint>
#include <list>
#include <memory>
#include <mutex>
#include <optional>
#include <string>

#include "common/engine/job_state.hpp"
#include "common/protocol/job_snapshot.hpp"
#include "server/jobs/job_store.hpp"

namespace tally {

class FinishedStateCache {
 public:
  FinishedStateCache(JobStore& store, uint64_t capacity_bytes, double oversize_idle_s = 30)
      : store_(store), capacity_(capacity_bytes), oversize_idle_s_(oversize_idle_s) {}

  // The finished job's state at the snapshot's version: cached, else read back from the
  // store's checkpoint (and cached if it fits). Null if the job is not finished or its
  // stored state is missing, unreadable or does not match the job (logged). May read
  // the disk: call it off the I/O threads.
  std::shared_ptr<const JobState> get(const JobSnapshot& s);
  // Drops every version of the job (deleted).
  void erase(const std::string& id);

  uint64_t bytes() const;   // decoded states kept (the oversize one included)
  uint64_t loads() const;   // states read back from the store since start

 private:
  std::shared_ptr<const JobState> load(const JobSnapshot& s);
  void erase_locked(const std::string& id);
  // Drops the oversize entry once it has been idle for oversize_idle_s.
  void expire_locked() const;

  struct Entry {
    std::string id;
    uint64_t version;
    std::shared_ptr<const JobState> state;
    uint64_t bytes;
  };
  JobStore& store_;
  const uint64_t capacity_;
  const double oversize_idle_s_;
  mutable std::mutex mu_;
  std::list<Entry> entries_;  // most recent first
  uint64_t bytes_ = 0;
  mutable std::optional<Entry> oversize_;  // a state over the capacity, while it is read
  mutable std::chrono::steady_clock::time_point oversize_used_{};
  uint64_t loads_ = 0;
};

}  // namespace tally
