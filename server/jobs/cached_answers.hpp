#pragma once
// Answering submits from the result cache: which finished jobs become sources (those
// whose result is the one their spec computes), and, for a submit whose spec and seed
// equal a source's that the submitter may read, the source's result and stored state,
// which the new job takes as its own (JobManager::submit builds and stores it).
//
// Thread-safety: safe from any thread; its only state is the ResultCache (its own
// lock). No threads inside. find() reads the store (a checkpoint): call it where a
// submit runs, off the I/O threads.
#include <cstdint>
#include <functional>
#include <optional>
#include <string>

#include "common/protocol/job_snapshot.hpp"
#include "server/jobs/admission.hpp"
#include "server/jobs/job.hpp"
#include "server/jobs/job_store.hpp"
#include "server/jobs/result_cache.hpp"

namespace tally {

class CachedAnswers {
 public:
  explicit CachedAnswers(JobStore& store) : store_(store) {}

  // Whether a job that ended with `facts` computed what its spec asks: it stopped for a
  // reason the clock does not decide, under its spec's own rule (not extended), and
  // this build's engine would compute the same bits (kResultsVersion).
  static bool answers_its_spec(const JobDefinition* def, const RunFacts* facts);
  // A finished job, stored as `status` with `facts`: a source for later submits of its
  // key from now, if it answers its spec.
  void offer(const Job& job, JobStatus status, const RunFacts* facts);

  struct Answer {
    std::string source;                                  // the job answering
    std::shared_ptr<const nlohmann::json> final_result;  // its result and facts
    std::shared_ptr<const RunFacts> facts;
    std::string checkpoint;  // its stored state
  };
  // The job as it is now (JobManager::snapshot), or nullopt if it is gone.
  using SnapshotOf = std::function<std::optional<JobSnapshot>(const std::string& id)>;
  // The answer to a submit of `key` by `who` within `max_samples`: the newest source
  // `who` may read, if it still reads as succeeded and its state reads back; else
  // nullopt, counted as a miss.
  std::optional<Answer> find(const std::string& key, const Submitter& who, uint64_t max_samples,
                             const SnapshotOf& snapshot_of);
  // A new job (not yet stored) becomes the answer: finished as the source, keyed `key`.
  static void answer(Job& job, const Answer& answer, const std::string& key, std::shared_ptr<const JobDefinition> def,
                     JobCaps caps);
  // `job` was stored as the answer (a hit); it answers later submits of `key` too.
  void answered(const std::string& key, const Job& job, uint64_t samples);
  void missed() { cache_.counted(false); }  // a submit that looked and computes
  void erase(const std::string& id) { cache_.erase(id); }  // deleted or reopened

  uint64_t hits() const { return cache_.hits(); }
  uint64_t misses() const { return cache_.misses(); }

 private:
  JobStore& store_;
  ResultCache cache_;
};

}  // namespace tally
