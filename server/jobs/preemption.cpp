#include "server/jobs/preemption.hpp"

#include "common/log/log.hpp"

namespace tally {

void Preemption::request_pauses(double now) {
  if (min_run_s_ < 0) return;
  while (std::shared_ptr<Job> victim = admission_.preemption_victim(now, min_run_s_)) {
    std::lock_guard jl(victim->mu_);
    victim->preempt_requested_ = true;
    log::job(log::Level::info, victim->id(), "pauses at its next pass boundary: a waiting job goes first");
  }
}

uint64_t Preemption::requeue(const std::shared_ptr<Job>& job) {
  uint64_t samples = 0, version = 0;
  {
    std::lock_guard jl(job->mu_);
    samples = job->pause_locked();
    version = job->version_;
  }
  admission_.stopped(*job);
  admission_.enqueue(job);
  ++preemptions_;
  log::job(log::Level::info, job->id(),
           "paused at a pass boundary ({} samples); queued until it resumes, its state being stored", samples);
  return version;
}

bool Preemption::release_stored(const std::shared_ptr<Job>& job, uint64_t version) {
  {
    std::lock_guard jl(job->mu_);
    if (job->status_ != JobStatus::queued || job->version_ != version || !job->runner_) return false;
    job->park_locked();
  }
  admission_.release(*job);
  log::job(log::Level::debug, job->id(), "the paused job's state is stored; it leaves memory");
  return true;
}

Preemption::Start Preemption::start_locked(const std::shared_ptr<Job>& job, double now) {
  if (!job->parked_ || job->runner_ || !job->def_) return Start::not_parked;
  if (job->loading_) return Start::loading;
  job->loading_ = true;
  admission_.charge(*job);
  admission_.started(job, now);
  return Start::load;
}

Preemption::Resumed Preemption::resumed(const std::shared_ptr<Job>& job, std::unique_ptr<JobRunner> runner,
                                        const std::string& error, double now, bool shutting_down) {
  admission_.stopped(*job);  // starting it counts it again
  std::lock_guard jl(job->mu_);
  if (job->status_ != JobStatus::queued || shutting_down) {
    // Cancelled meanwhile, or shutting down (its state stays on disk): not started.
    job->loading_ = false;
    if (job->status_ != JobStatus::queued) admission_.release(*job);
    return Resumed::dropped;
  }
  if (job->resumed_locked(std::move(runner), error, now)) return Resumed::start;
  admission_.release(*job);
  return Resumed::failed;
}

bool Preemption::readmit_locked(const std::shared_ptr<Job>& job, uint64_t owner_max_running) {
  const uint64_t bytes = job->def_ ? Admission::memory_bytes(*job->def_) : 0;
  admission_.track(*job, bytes, owner_max_running);
  if (job->runner_ && !is_terminal(job->status_) && !admission_.fits(bytes)) {
    // Resumed beyond the memory budget: its state goes back to disk until it starts.
    job->park_locked();
  }
  if (job->runner_) admission_.charge(*job);  // resumed from a checkpoint: its state is in memory
  if (is_terminal(job->status_)) return false;
  job->status_ = JobStatus::queued;
  admission_.enqueue(job);
  log::job(log::Level::info, job->id(), "resumes from its checkpoint ({} samples)",
           job->runner_ ? job->runner_->state().samples : 0);
  return true;
}

}  // namespace tally
