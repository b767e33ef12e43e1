// JobManager's side of preemption (docs/api.md "Preemption"; the policy is
// Preemption's, server/jobs/preemption.hpp): a job paused at its pass boundary, its
// state stored and released off the thread that paused it, and a parked job's state read
// back before it starts. Beside job_manager.cpp, which holds the rest of the lifecycle.
#include "common/log/log.hpp"
#include "server/jobs/job_manager.hpp"

namespace tally {

void JobManager::pause(const std::shared_ptr<Job>& job) {
  // The slot is free at once: the job that goes first starts now (if the memory budget
  // lets it beside this one's state), not after this state is written (hundreds of ms
  // for an image). The state is stored on the recorder's loader thread, so this thread
  // (a worker; in cluster mode the coordinator) goes on too; once stored it leaves
  // memory. Until then the paused job waits with its state in memory: if it is started
  // again first, it goes on from there; if the store fails, it stays so.
  uint64_t version = 0;
  {
    std::lock_guard lock(mu_);
    version = preemption_.requeue(job);
    start_queued_locked();
  }
  recorder_.load_later([this, job, version] {
    if (!recorder_.persist(*job, true, false)) return;
    std::lock_guard lock(mu_);
    if (preemption_.release_stored(job, version)) start_queued_locked();
  });
}

void JobManager::resume_loaded(const std::shared_ptr<Job>& job) {
  std::shared_ptr<const JobDefinition> def;
  StopRule rule;
  {
    std::lock_guard jl(job->mu_);
    def = job->def_;
    rule = job->facts_ ? job->facts_->rule : def->stop_rule();
  }
  std::unique_ptr<JobRunner> runner;
  std::string error;
  try {
    runner = recorder_.read_back(*job, *def, rule);
  } catch (const std::exception& e) {
    error = e.what();
    log::job(log::Level::warn, job->id(), "reading its stored state back to go on failed: {}", error);
  }
  Preemption::Resumed r;
  {
    std::lock_guard lock(mu_);
    r = preemption_.resumed(job, std::move(runner), error, unix_now(), shutting_down_);
    if (r == Preemption::Resumed::start) start_locked(job);
    if (r != Preemption::Resumed::dropped) start_queued_locked();
  }
  if (r == Preemption::Resumed::failed) recorder_.persist(*job, false);
}

}  // namespace tally
