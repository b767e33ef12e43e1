// JobManager::set_priority (PATCH /v1/jobs/{id}, docs/api.md "Changing a priority"): a
// queued or running job's priority from now on. Its own file beside job_manager.cpp so
// the lifecycle file stays within the structure limit (tests/structure/layering.cmake).
#include <fmt/format.h>

#include "common/log/log.hpp"
#include "server/executor/in_process_executor.hpp"
#include "server/jobs/job_manager.hpp"

namespace tally {

std::shared_ptr<Job> JobManager::set_priority(const std::string& id, int priority) {
  std::shared_ptr<Job> job = find(id);
  if (!job) throw JobError(JobError::Kind::not_found, fmt::format("no job with id \"{}\"", id));
  const auto apply = [&](int p, bool put_back) {  // manager's lock (Admission reads under it), job's, executor's
    std::lock_guard lock(mu_);
    const int was = job->set_priority(p, put_back);
    executor_->set_priority(id, p);
    start_queued_locked();  // a raised job may start first or preempt; a lowered one give way
    return was;
  };
  const int was = apply(clamp_priority(priority), false);
  if (!recorder_.persist(*job, false, false)) {
    apply(was, true);  // not stored: as it was, even if it has finished meanwhile
    throw JobError(JobError::Kind::unavailable, fmt::format("the job store is failing ({}); the priority was not "
                                                            "changed, retry later",
                                                            recorder_.store_problem().value_or("unknown error")));
  }
  log::job(log::Level::info, id, "priority {} -> {}", was, job->priority());
  return job;
}

}  // namespace tally
