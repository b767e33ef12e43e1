#include "server/jobs/manager_stats.hpp"

#include "server/jobs/job.hpp"

namespace tally {

void add_job_figures(ManagerStats& s, const std::vector<std::shared_ptr<Job>>& jobs, unsigned workers) {
  for (JobStatus st : {JobStatus::queued, JobStatus::running, JobStatus::succeeded, JobStatus::failed,
                       JobStatus::cancelled}) {
    s.jobs_by_state[std::string(job_status_name(st))] = 0;
  }
  // The scaling signal: the jobs' own forecasts (Job::forecast_locked), a running job on
  // its share of the workers.
  size_t running = 0;
  for (const auto& j : jobs) {
    std::lock_guard jl(j->mu_);
    if (j->status_ == JobStatus::running) ++running;
  }
  const double share = running > 0 ? static_cast<double>(workers) / static_cast<double>(running) : 1.0;
  for (const auto& j : jobs) {
    std::lock_guard jl(j->mu_);
    s.jobs_by_state[std::string(job_status_name(j->status_))]++;
    if (j->status_ == JobStatus::running && j->runner_ && !j->merging_) {
      s.samples_per_second += j->runner_->samples_per_second();  // (not while a pass merges into it)
    }
    j->forecast_locked(share, s.predicted_cpu_seconds_running, s.predicted_cpu_seconds_queued);
  }
}

}  // namespace tally
