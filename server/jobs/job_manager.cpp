#include "server/jobs/job_manager.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <chrono>

#include "common/engine/checkpoint.hpp"
#include "common/log/log.hpp"
#include "common/protocol/job_json.hpp"
#include "common/spec/spec_reader.hpp"
#include "server/executor/in_process_executor.hpp"
#include "server/jobs/pass_views.hpp"

namespace tally {

using nlohmann::json;

namespace {

double steady_seconds() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

std::string dump(const json& j) { return j.dump(-1, ' ', false, json::error_handler_t::replace); }

}  // namespace

JobManager::JobManager(ManagerConfig config, JobStore& store, JobCompiler compiler)
    : config_(std::move(config)), compiler_(std::move(compiler)),
      recorder_(store, compiler_, config_.limits, config_.event_buffer),
      admission_(Admission::Limits{config_.max_running, config_.max_queued, config_.memory_budget}),
      preemption_(admission_, config_.preempt_min_run_s), store_(store), finished_(store, config_.finished_cache_bytes),
      retention_(JobRetention::Policy{config_.retain_max_age_s, config_.retain_max_jobs, config_.retain_max_bytes,
                                      config_.retention_interval_s}),
      answers_(store) {
  recorder_.set_copy_bytes(config_.checkpoint_copy_bytes);
  ExecutorCallbacks cb;
  cb.pass_done = [this](const std::string& id, const PassWork& done, std::vector<BlockResult>&& results,
                        double wall) { return on_pass_done(id, done, std::move(results), wall); };
  cb.group_done = [this](const std::string& id, const PassWork& pass, size_t group, BlockResult&& result) {
    if (const std::shared_ptr<Job> job = find(id)) job->merge_group(std::move(result), pass.pass, group);
  };
  cb.merges_held = [this](const std::string& id) {
    const std::shared_ptr<Job> job = find(id);
    return job && job->merges_held();
  };
  cb.cancelled = [this](const std::string& id) { on_stopped(id, std::nullopt); };
  cb.failed = [this](const std::string& id, const std::string& error) { on_stopped(id, error); };
  executor_ = config_.make_executor
                  ? config_.make_executor(std::move(cb))
                  : std::make_unique<InProcessExecutor>(config_.workers, std::move(cb), config_.chunk_target_s);
}

JobManager::~JobManager() {
  {
    std::lock_guard lock(mu_);
    shutting_down_ = true;  // a final save's release_state starts no queued job now
  }
  recorder_.stop_loads();  // reads of parked states under way end (they start nothing now)
  retention_.stop();
  executor_->stop();
  recorder_.flush_finals();  // their callbacks use this manager
}

std::optional<std::string> JobManager::not_ready_reason() const {
  if (auto p = recorder_.store_problem()) return fmt::format("the job store is failing: {}", *p);
  return std::nullopt;
}

// ---------------------------------------------------------------- snapshots

JobSnapshot JobManager::snapshot(const Job& job, SnapshotOf of) const {
  JobSnapshot s = job.snapshot(*executor_, of == SnapshotOf::state);
  if (s.status == JobStatus::queued && s.executor.waiting_reason.empty()) {
    std::lock_guard lock(mu_);
    if (admission_.owner_at_quota(job)) s.executor.waiting_reason = "owner at max_running_jobs";
  }
  return s;
}

JobSnapshot JobManager::snapshot(const std::string& id, SnapshotOf of) const {
  const std::shared_ptr<Job> job = find(id);
  if (!job) throw JobError(JobError::Kind::not_found, fmt::format("no job with id \"{}\"", id));
  return snapshot(*job, of);
}

std::vector<JobSnapshot> JobManager::snapshots() const {
  std::vector<JobSnapshot> out;
  for (const auto& job : list()) out.push_back(snapshot(*job));
  return out;
}

std::vector<Event> JobManager::watch_snapshot(const Job& job) const { return job.watch_snapshot(); }

JobStatus JobManager::status(const Job& job) const {
  std::lock_guard lock(job.mu_);
  return job.status_;
}

// ---------------------------------------------------------------- lifecycle

std::unique_ptr<JobDefinition> JobManager::compile(const json& spec, const JobLimits& limits) const {
  return compile_within_budget(compiler_, spec, limits, admission_);
}

bool JobManager::reserve_memory(uint64_t bytes) {
  std::lock_guard lock(mu_);
  return admission_.reserve(bytes);
}

void JobManager::check_room(const Submitter& who) const {
  std::lock_guard lock(mu_);
  admission_.check_room(who);
}

void JobManager::release_memory(uint64_t bytes) {
  std::lock_guard lock(mu_);
  admission_.unreserve(bytes);
  start_queued_locked();  // the memory freed may let a waiting job start
}

std::shared_ptr<Job> JobManager::submit(const json& spec, int priority, const Submitter& who, bool use_cache) {
  const JobLimits& limits = who.limits ? *who.limits : config_.limits;
  // Throws SpecError; also for a job whose state could never fit the memory budget (the
  // state is allocated when the job starts: it is refused now).
  std::shared_ptr<const JobDefinition> def = compile(spec, limits);
  const std::string key = ResultCache::key_of(spec, def->seed());
  if (use_cache) {
    const auto snapshot_of = [this](const std::string& id) -> std::optional<JobSnapshot> {
      const std::shared_ptr<Job> src = find(id);
      return src ? std::optional<JobSnapshot>(snapshot(*src)) : std::nullopt;
    };
    if (auto answer = answers_.find(key, who, limits.caps().max_samples, snapshot_of)) {
      return answer_from(std::move(*answer), spec, priority, who, std::move(def), limits, key);
    }
  }
  const uint64_t need = Admission::memory_bytes(*def);
  std::shared_ptr<Job> job;
  {
    std::lock_guard lock(mu_);
    if (shutting_down_) throw JobError(JobError::Kind::unavailable, "the server is shutting down");
    admission_.check_room(who);
    job = new_job_locked(spec, priority, who);
    job->cache_key_ = key;
    job->caps_ = limits.caps();
    job->facts_ = std::make_shared<const RunFacts>(fresh_run_facts(def->stop_rule()));
    job->def_ = std::move(def);
  }
  // Acknowledged only once stored: a job the store did not take is not kept.
  if (!recorder_.persist(*job, false, false)) {
    throw JobError(JobError::Kind::unavailable,
                   fmt::format("the job store is failing ({}); the job was not accepted, retry later",
                               recorder_.store_problem().value_or("unknown error")));
  }
  log::job(log::Level::info, job->id(), "submitted: kind {}, priority {}", job->def_->kind(), job->priority());
  {
    std::lock_guard lock(mu_);
    jobs_[job->id()] = job;
    order_.push_back(job);
    admission_.track(*job, need, who.max_running);
    admission_.enqueue(job);
    start_queued_locked();
  }
  return job;
}

std::shared_ptr<Job> JobManager::new_job_locked(const json& spec, int priority, const Submitter& who) {
  return std::make_shared<Job>(new_job_id(), next_seq_++, spec, clamp_priority(priority), unix_now(), epoch_,
                               config_.event_buffer, who.owner);
}

std::shared_ptr<Job> JobManager::answer_from(CachedAnswers::Answer answer, const json& spec, int priority,
                                             const Submitter& who, std::shared_ptr<const JobDefinition> def,
                                             const JobLimits& limits, const std::string& key) {
  std::shared_ptr<Job> job;
  {
    std::lock_guard lock(mu_);
    if (shutting_down_) throw JobError(JobError::Kind::unavailable, "the server is shutting down");
    job = new_job_locked(spec, priority, who);
  }
  const uint64_t need = Admission::memory_bytes(*def);
  CachedAnswers::answer(*job, answer, key, std::move(def), limits.caps());
  // Acknowledged only once stored, with the source's state as its own.
  if (!recorder_.persist_with(*job, std::move(answer.checkpoint))) {
    throw JobError(JobError::Kind::unavailable,
                   fmt::format("the job store is failing ({}); the job was not accepted, retry later",
                               recorder_.store_problem().value_or("unknown error")));
  }
  {
    std::lock_guard lock(mu_);
    jobs_[job->id()] = job;
    order_.push_back(job);
    admission_.track(*job, need, who.max_running);
  }
  answers_.answered(key, *job, answer.facts->samples);
  log::job(log::Level::info, job->id(), "answered from job {}'s stored result (the same spec and seed)",
           answer.source);
  return job;
}

void JobManager::start_queued_locked() {
  while (!shutting_down_) {
    std::shared_ptr<Job> job = admission_.next();
    if (!job) break;
    start_locked(job);
  }
  preempt_locked();
}

void JobManager::preempt_locked() {
  if (!shutting_down_) preemption_.request_pauses(steady_seconds());
}

void JobManager::start_locked(const std::shared_ptr<Job>& job) {
  ExecutorJob ej;
  std::optional<PassWork> pass;
  {
    std::lock_guard jl(job->mu_);
    if (job->status_ != JobStatus::queued) return;
    switch (preemption_.start_locked(job, steady_seconds())) {
      case Preemption::Start::not_parked: break;
      case Preemption::Start::loading: return;
      case Preemption::Start::load:  // read back on the recorder's loader thread, then it starts
        recorder_.load_later([this, job] { resume_loaded(job); });
        return;
    }
    pass = job->start_running_locked(epoch_, unix_now(), ej);
    // A state whose checkpoint streams from the live one (an image's) has its passes
    // streamed too: merged group by group, never a pass's results held beside it.
    ej.stream_groups = config_.stream_passes && pass && job->runner_ &&
                       checkpoint_size_hint(job->runner_->state()) > config_.checkpoint_copy_bytes;
  }
  if (!pass) return;
  admission_.charge(*job);
  if (pass->empty()) {
    // Nothing to run (restored already complete, e.g. killed after its last pass): it
    // ended at start. Store it off this lock, on the recorder's loader thread; once
    // stored it is a finished job like any other: it may answer submits of its spec,
    // and its state leaves memory (the charge above is released).
    recorder_.load_later([this, job] {
      if (!recorder_.persist(*job, true)) return;  // retried until stored; it stays in memory
      JobStatus status;
      std::shared_ptr<const RunFacts> facts;
      {
        std::lock_guard jl(job->mu_);
        status = job->status_;
        facts = job->facts_;
      }
      answers_.offer(*job, status, facts.get());
      release_state(*job);
    });
    return;
  }
  log::job(log::Level::debug, job->id(), "running");
  admission_.started(job, steady_seconds());
  executor_->add(std::move(ej), std::move(*pass));
}

void JobManager::release_state(Job& job) {
  std::lock_guard lock(mu_);
  {
    std::lock_guard jl(job.mu_);
    if (!is_terminal(job.status_) || !job.runner_) return;
    if (!job.facts_) job.facts_ = std::make_shared<const RunFacts>(run_facts(*job.runner_));
    job.runner_.reset();
    job.published_.reset();
  }
  admission_.release(job);
  start_queued_locked();  // the memory freed may let a waiting job start
}

void JobManager::job_left_scheduler(const Job& job) {
  std::lock_guard lock(mu_);
  admission_.stopped(job);
  start_queued_locked();
}

PassWork JobManager::on_pass_done(const std::string& id, const PassWork& done, std::vector<BlockResult>&& results,
                                  double wall) {
  const std::shared_ptr<Job> job = find(id);
  if (!job) return {};
  {
    std::lock_guard lock(mu_);
    preempt_locked();  // a job may have run long enough to give way by now
  }
  using Clock = std::chrono::steady_clock;
  const auto t0 = Clock::now();
  Job::PassCommit c;
  {
    // A checkpoint streaming the state is abandoned (JobRecorder::store): waited for
    // one piece's encoding at most. The merge itself runs without the job's lock
    // (merge_pass), so its readers do not wait for it.
    std::lock_guard state_lock(job->state_mu_);
    job->merge_pass(std::move(results), wall, done.pass);
    std::lock_guard lock(job->mu_);
    c = job->commit_pass_locked(config_.checkpoint_interval_s);
  }
  const auto t_committed = Clock::now();
  FinishViews views;
  const JobEnding ending = job->publish_pass(done.blocks, c, views);
  const auto ms = [](Clock::time_point a, Clock::time_point b) {
    return std::chrono::duration<double, std::milli>(b - a).count();
  };
  log::job(log::Level::debug, job->id(), "pass {} boundary: commit and plan {:.3f} ms, views and publish {:.3f} ms",
           done.pass, ms(t0, t_committed), ms(t_committed, Clock::now()));
  // A periodic checkpoint is written on the recorder's thread while the next pass runs.
  // The last save (the ending and the final checkpoint) on its finisher thread: this
  // thread goes on at once (a worker; in cluster mode the coordinator), the job reads
  // as finished once it is stored, and its state then leaves memory (if the save
  // failed, it stays until a retried save succeeds; the image routes read it from memory).
  if (c.pause_now) {
    pause(job);
    return {};
  }
  if (c.checkpoint && !c.finished) recorder_.checkpoint_later(job);
  if (c.finished) {
    auto shown = std::make_shared<const FinishViews>(std::move(views));
    recorder_.save_final_later(job, ending, [this, job, ending, shown](bool stored) {
      // Stored: its result may answer later submits of the same spec (from when it reads
      // as finished, just below).
      if (stored) answers_.offer(*job, ending.status, ending.facts.get());
      {
        std::lock_guard lock(job->mu_);
        job->end_locked(ending, shown.get());  // its events, then state and end, under one lock
      }
      if (stored) {
        release_state(*job);
      } else {
        recorder_.persist(*job, true);  // retried until stored, now as it reads
      }
    });
    job_left_scheduler(*job);
  }
  return c.next;
}

void JobManager::on_stopped(const std::string& id, const std::optional<std::string>& error) {
  const std::shared_ptr<Job> job = find(id);
  if (!job) return;
  {
    std::lock_guard lock(job->mu_);
    if (is_terminal(job->status_) || job->finishing_) return;
    // The partial pass was dropped; the runner is at its last pass boundary.
    if (error) {
      job->runner_->fail(*error);
    } else {
      job->runner_->cancel();
    }
    job->finish_locked(unix_now());
  }
  if (recorder_.persist(*job, true)) release_state(*job);
  job_left_scheduler(*job);
}

std::shared_ptr<Job> JobManager::find(const std::string& id) const {
  std::lock_guard lock(mu_);
  auto it = jobs_.find(id);
  return it == jobs_.end() ? nullptr : it->second;
}

std::vector<std::shared_ptr<Job>> JobManager::list() const {
  std::lock_guard lock(mu_);
  return order_;
}

std::shared_ptr<Job> JobManager::cancel(const std::string& id) {
  std::shared_ptr<Job> job = find(id);
  if (!job) throw JobError(JobError::Kind::not_found, fmt::format("no job with id \"{}\"", id));
  bool was_queued = false;
  {
    std::lock_guard lock(mu_);
    std::lock_guard jl(job->mu_);
    if (is_terminal(job->status_)) {
      throw JobError(JobError::Kind::conflict,
                     fmt::format("job {} has already finished ({})", id, job_status_name(job->status_)));
    }
    if (job->finishing_) {
      throw JobError(JobError::Kind::conflict,
                     fmt::format("job {} has already finished; its result is being stored", id));
    }
    if (job->status_ == JobStatus::queued) {
      admission_.dequeue(*job);
      job->cancel_queued_locked(unix_now());
      was_queued = true;
    } else {
      job->cancel_requested_ = true;
      log::job(log::Level::info, id, "cancel requested; blocks in flight stop early and the partial pass is dropped");
    }
  }
  if (was_queued) {
    if (recorder_.persist(*job, true)) release_state(*job);
    return job;
  }
  executor_->cancel(id);  // may run on_cancelled right here
  return job;
}

std::shared_ptr<Job> JobManager::extend(const std::string& id, const StopRule& rule, const Submitter& who) {
  std::shared_ptr<Job> job = find(id);
  if (!job) throw JobError(JobError::Kind::not_found, fmt::format("no job with id \"{}\"", id));
  // A finished job's state is on disk: read it back (outside the locks) to go on.
  std::unique_ptr<JobRunner> loaded;
  if (const JobSnapshot s = snapshot(*job, SnapshotOf::state);
      is_terminal(s.status) && s.status != JobStatus::failed && !s.runner && s.def && s.facts) {
    try {
      loaded = recorder_.read_back(*job, *s.def, s.facts->rule);
    } catch (const std::exception& e) {
      log::job(log::Level::warn, id, "reading the stored state to extend failed: {}", e.what());
      throw JobError(JobError::Kind::conflict, fmt::format("job {}'s stored state cannot be read: {}", id, e.what()));
    }
  }
  {
    std::lock_guard lock(mu_);
    if (shutting_down_) throw JobError(JobError::Kind::unavailable, "the server is shutting down");
    std::lock_guard jl(job->mu_);
    // The job waits again: the same room as a submit (the server's queue, the owner's
    // max_queued) — asked after the job's own conflicts, which name it.
    const bool from_disk = job->extend_locked(rule, std::move(loaded), [&] { admission_.check_room(who); });
    if (!from_disk) admission_.charge(*job);
  }
  answers_.erase(id);  // its result changes
  log::job(log::Level::info, id, "extended; queued again");
  recorder_.persist(*job, false);
  std::lock_guard lock(mu_);
  admission_.enqueue(job);
  start_queued_locked();
  return job;
}

// ---------------------------------------------------------------- recovery, shutdown

void JobManager::recover(const MaxRunningOf& max_running_of) {
  JobRecorder::Recovered rec = recorder_.recover();
  epoch_ = rec.epoch;
  size_t resumed = 0;
  {
    std::lock_guard lock(mu_);
    for (auto& job : rec.jobs) {
      jobs_[job->id()] = job;
      order_.push_back(job);
      next_seq_ = std::max(next_seq_, job->seq() + 1);
      std::lock_guard jl(job->mu_);
      if (job->def_) job->cache_key_ = ResultCache::key_of(job->spec(), job->def_->seed());
      answers_.offer(*job, job->status_, job->facts_.get());
      const uint64_t max_running = max_running_of ? max_running_of(job->owner()) : UINT64_MAX;
      if (preemption_.readmit_locked(job, max_running)) ++resumed;
    }
    if (!rec.jobs.empty()) log::info("recovered {} jobs ({} resume), epoch {}", rec.jobs.size(), resumed, epoch_);
    start_queued_locked();
  }
  apply_retention();
  retention_.start([this] { apply_retention(); });
}

// ---------------------------------------------------------------- removal, retention

void JobManager::remove(const std::string& id) {
  std::shared_ptr<Job> job;
  {
    std::lock_guard lock(mu_);
    auto it = jobs_.find(id);
    if (it == jobs_.end()) throw JobError(JobError::Kind::not_found, fmt::format("no job with id \"{}\"", id));
    job = it->second;
    std::lock_guard jl(job->mu_);
    if (!is_terminal(job->status_)) {
      throw JobError(JobError::Kind::conflict,
                     fmt::format("job {} is still {}; cancel it before deleting it", id, job_status_name(job->status_)));
    }
    // The row first (a quick SQLite delete): if the store fails, the job stays whole.
    try {
      store_.remove(id);
    } catch (const std::exception& e) {
      log::job(log::Level::warn, id, "deleting the job from the store failed: {}", e.what());
      throw JobError(JobError::Kind::unavailable, fmt::format("the job store is failing ({}); retry later", e.what()));
    }
    jobs_.erase(it);
    order_.erase(std::remove(order_.begin(), order_.end(), job), order_.end());
    admission_.forget(*job);
    ++jobs_removed_;
  }
  finished_.erase(id);
  answers_.erase(id);
  recorder_.removed(*job);
  job->events_.close();
  log::job(log::Level::info, id, "deleted");
}

std::vector<std::string> JobManager::apply_retention() {
  if (!retention_.policy().any()) return {};
  std::vector<std::string> removed;
  for (const JobRetention::Retire& r : retention_.select(finished_jobs(list()), unix_now())) {
    try {
      remove(r.id);
      log::job(log::Level::info, r.id, "deleted by retention: {}", r.why);
      removed.push_back(r.id);
    } catch (const JobError& e) {
      // Extended or deleted meanwhile: it is no longer a finished job to retire.
      log::job(log::Level::debug, r.id, "retention skipped it: {}", e.what());
    }
  }
  if (!removed.empty()) log::info("retention deleted {} finished jobs", removed.size());
  return removed;
}

// ---------------------------------------------------------------- finished states

std::shared_ptr<const JobState> JobManager::state(const JobSnapshot& s) {
  if (s.runner) return std::shared_ptr<const JobState>(s.runner, &s.runner->state());
  return finished_.get(s);
}

void JobManager::shutdown() {
  {
    std::lock_guard lock(mu_);
    if (shutting_down_) return;
    shutting_down_ = true;
  }
  recorder_.stop_loads();
  retention_.stop();
  executor_->stop();  // chunks in flight finish; partial passes are dropped
  recorder_.flush_finals();  // jobs that ended just before are stored and read as finished
  for (const auto& job : list()) {
    bool unfinished;
    {
      std::lock_guard jl(job->mu_);
      unfinished = !is_terminal(job->status_);
    }
    if (unfinished && job->mid_pass()) {
      // Part of a streamed pass is merged: no checkpoint (it would count that part
      // twice on resume); the last one stands.
      recorder_.persist(*job, false);
      log::job(log::Level::info, job->id(), "stopped inside a pass; resumes on restart from its last checkpoint");
    } else if (unfinished) {
      recorder_.persist(*job, true);  // the state at its last pass boundary
      log::job(log::Level::info, job->id(), "checkpointed for shutdown; resumes on restart");
    }
    job->events_.append("shutdown",
                        dump(json{{"reason", "the server is shutting down"}, {"resumes", unfinished}}));
    job->events_.close();
  }
}

bool JobManager::shutting_down() const {
  std::lock_guard lock(mu_);
  return shutting_down_;
}

ManagerStats JobManager::stats() const {
  ManagerStats s;
  std::vector<std::shared_ptr<Job>> jobs;
  {
    std::lock_guard lock(mu_);
    jobs = order_;
    s.queue_depth = admission_.queued();
  }
  const ExecutorStats es = executor_->stats();
  add_job_figures(s, jobs, es.workers);
  s.samples_total = es.samples_done;
  s.groups_streamed = es.groups_streamed;
  s.workers = es.workers;
  s.busy_workers = es.busy_workers;
  s.store_failures = recorder_.store_failures();
  s.store_ok = !recorder_.store_problem().has_value();
  s.cpu_seconds_by_owner = es.cpu_seconds_by_owner;
  {
    std::lock_guard lock(mu_);
    s.memory_budget = admission_.memory_budget();
    s.memory_used = admission_.memory_used();
    s.jobs_removed = jobs_removed_;
    s.preemptions = preemption_.preemptions();
  }
  s.result_cache_hits = answers_.hits();
  s.result_cache_misses = answers_.misses();
  s.finished_cache_bytes = finished_.bytes();
  s.state_loads = finished_.loads();
  return s;
}

}  // namespace tally
