#include "server/jobs/job_manager.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <random>

#include "common/engine/checkpoint.hpp"
#include "common/log/log.hpp"
#include "common/protocol/job_json.hpp"
#include "common/spec/spec_reader.hpp"
#include "server/executor/in_process_executor.hpp"
#include "server/jobs/pass_views.hpp"

namespace tally {

using nlohmann::json;

namespace {
// A finished job whose result is the one its spec computes (ResultCache): it stopped
// for a reason the clock does not decide, under its spec's own rule (not extended).
bool answers_its_spec(const JobDefinition* def, const RunFacts* f) {
  if (!def || !f || !ResultCache::reusable(f->stop_reason)) return false;
  const StopRule a = f->rule, b = def->stop_rule();
  return a.max_samples == b.max_samples && a.time_budget_s == b.time_budget_s && a.abs_error == b.abs_error &&
         a.rel_error == b.rel_error && a.confidence == b.confidence && a.min_samples == b.min_samples;
}
}  // namespace

double unix_now() {
  return std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
}

namespace {

std::string new_job_id() {
  static std::mutex mu;
  static std::mt19937_64 rng{std::random_device{}() ^
                             static_cast<uint64_t>(std::chrono::steady_clock::now().time_since_epoch().count())};
  std::lock_guard lock(mu);
  return fmt::format("{:016x}", rng());
}

std::string dump(const json& j) { return j.dump(-1, ' ', false, json::error_handler_t::replace); }

}  // namespace

JobManager::JobManager(ManagerConfig config, JobStore& store, JobCompiler compiler)
    : config_(std::move(config)), compiler_(std::move(compiler)),
      recorder_(store, compiler_, config_.limits, config_.event_buffer),
      admission_(Admission::Limits{config_.max_running, config_.max_queued, config_.memory_budget}), store_(store),
      finished_(store, config_.finished_cache_bytes),
      retention_(JobRetention::Policy{config_.retain_max_age_s, config_.retain_max_jobs, config_.retain_max_bytes,
                                      config_.retention_interval_s}) {
  ExecutorCallbacks cb;
  cb.pass_done = [this](const std::string& id, const PassWork& done, std::vector<BlockResult>&& results,
                        double wall) { return on_pass_done(id, done, std::move(results), wall); };
  cb.cancelled = [this](const std::string& id) { on_cancelled(id); };
  cb.failed = [this](const std::string& id, const std::string& error) { on_failed(id, error); };
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
  // What the executor says about the job (cluster mode: why it waits, blocks pending /
  // in flight), asked before taking the job's lock (executor locks are never nested in it).
  ExecutorNote note;
  if (auto why = executor_->waiting_reason(job.id_)) note.waiting_reason = *why;
  note.held_queued = executor_->holds_queued(job.id_);
  if (const ExecutorStats es = executor_->stats(); es.blocks_by_job.count(job.id_)) {
    const auto& b = es.blocks_by_job.at(job.id_);
    note.has_blocks = true;
    note.pending = b.pending;
    note.in_flight = b.in_flight;
    note.redelivered = b.redelivered;
  }
  std::lock_guard lock(job.mu_);
  JobSnapshot s = job.snapshot_locked(of == SnapshotOf::state);
  if (job.preempted_ && job.status_ == JobStatus::queued) note.waiting_reason = "preempted";
  // Started, but nothing can compute it yet (cluster: no live worker in its pool).
  if (s.status == JobStatus::running && note.held_queued) s.status = JobStatus::queued;
  s.executor = std::move(note);
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
    if (const auto source = results_.find(key, who.owner, who.reads_all, limits.caps().max_samples)) {
      if (auto job = answer_from(*source, spec, priority, who, def, limits, key)) {
        results_.counted(true);
        return job;
      }
    }
    results_.counted(false);
  }
  const uint64_t need = Admission::memory_bytes(*def);
  std::shared_ptr<Job> job;
  {
    std::lock_guard lock(mu_);
    if (shutting_down_) throw JobError(JobError::Kind::unavailable, "the server is shutting down");
    admission_.check_room(who);
    job = std::make_shared<Job>(new_job_id(), next_seq_++, spec, clamp_priority(priority), unix_now(), epoch_,
                                config_.event_buffer, who.owner);
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

namespace {
double steady_seconds() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}
}  // namespace

std::shared_ptr<Job> JobManager::answer_from(const std::string& source, const json& spec, int priority,
                                             const Submitter& who, std::shared_ptr<const JobDefinition> def,
                                             const JobLimits& limits, const std::string& key) {
  const std::shared_ptr<Job> src = find(source);
  if (!src) return nullptr;
  const JobSnapshot s = snapshot(*src);
  if (s.status != JobStatus::succeeded || !s.final_result || !s.facts) return nullptr;
  std::optional<std::string> checkpoint;
  try {
    checkpoint = store_.load_checkpoint(source);
  } catch (const std::exception& e) {
    log::job(log::Level::warn, source, "reading its stored state to answer a submit from it failed: {}", e.what());
  }
  if (!checkpoint) return nullptr;
  std::shared_ptr<Job> job;
  {
    std::lock_guard lock(mu_);
    if (shutting_down_) throw JobError(JobError::Kind::unavailable, "the server is shutting down");
    job = std::make_shared<Job>(new_job_id(), next_seq_++, spec, clamp_priority(priority), unix_now(), epoch_,
                                config_.event_buffer, who.owner);
  }
  job->cache_key_ = key;
  job->cached_from_ = source;
  const uint64_t need = Admission::memory_bytes(*def);
  {
    std::lock_guard jl(job->mu_);
    job->answer_locked(std::move(def), limits.caps(),
                       JobEnding{JobStatus::succeeded, "", job->created_at(), s.final_result, s.facts});
  }
  // Acknowledged only once stored, with the source's state as its own.
  if (!recorder_.persist_with(*job, std::move(*checkpoint))) {
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
  results_.add(key, job->id(), job->owner(), s.facts->samples);
  log::job(log::Level::info, job->id(), "answered from job {}'s stored result (the same spec and seed)", source);
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
  if (config_.preempt_min_run_s < 0 || shutting_down_) return;
  while (std::shared_ptr<Job> victim = admission_.preemption_victim(steady_seconds(), config_.preempt_min_run_s)) {
    std::lock_guard jl(victim->mu_);
    victim->preempt_requested_ = true;
    log::job(log::Level::info, victim->id(), "pauses at its next pass boundary: a waiting job goes first");
  }
}

void JobManager::pause(const std::shared_ptr<Job>& job) {
  // Its state at this pass boundary is stored before it leaves memory.
  const bool stored = recorder_.persist(*job, true, false);
  uint64_t samples = 0;
  std::lock_guard lock(mu_);
  {
    std::lock_guard jl(job->mu_);
    samples = job->pause_locked(stored);
  }
  if (stored) admission_.release(*job);
  admission_.stopped(*job);
  admission_.enqueue(job);
  ++preemptions_;
  log::job(log::Level::info, job->id(), "paused at a pass boundary ({} samples{}); queued until it resumes", samples,
           stored ? ", state stored and released" : ", state kept: the store failed");
  start_queued_locked();
}

void JobManager::start_locked(const std::shared_ptr<Job>& job) {
  ExecutorJob ej;
  std::optional<PassWork> pass;
  {
    std::lock_guard jl(job->mu_);
    if (job->status_ != JobStatus::queued) return;
    if (job->parked_ && !job->runner_ && job->def_) {
      // Its state is on disk: read back on the recorder's loader thread, then it starts
      // (resume_loaded). It holds its running slot and its memory from now.
      if (job->loading_) return;
      job->loading_ = true;
      admission_.charge(*job);
      admission_.started(job, steady_seconds());
      recorder_.load_later([this, job] { resume_loaded(job); });
      return;
    }
    pass = job->start_running_locked(epoch_, unix_now(), ej);
  }
  if (!pass) return;
  admission_.charge(*job);
  if (pass->empty()) {
    // Nothing to run (restored already complete): store the final state.
    recorder_.persist(*job, true);
    return;
  }
  log::job(log::Level::debug, job->id(), "running");
  admission_.started(job, steady_seconds());
  executor_->add(std::move(ej), std::move(*pass));
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
  bool failed = false;
  {
    std::lock_guard lock(mu_);
    admission_.stopped(*job);  // start_locked counts it again
    {
      std::lock_guard jl(job->mu_);
      if (job->status_ != JobStatus::queued || shutting_down_) {
        // Cancelled meanwhile, or shutting down (its state stays on disk): not started.
        job->loading_ = false;
        if (job->status_ != JobStatus::queued) admission_.release(*job);
        return;
      }
      failed = !job->resumed_locked(std::move(runner), error, unix_now());
      if (failed) admission_.release(*job);
    }
    if (!failed) start_locked(job);
    start_queued_locked();
  }
  if (failed) recorder_.persist(*job, false);
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
    std::lock_guard lock(job->mu_);
    c = job->commit_pass_locked(std::move(results), wall, done.pass, config_.checkpoint_interval_s);
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
      if (stored && ending.status == JobStatus::succeeded && answers_its_spec(job->def_.get(), ending.facts.get())) {
        results_.add(job->cache_key_, job->id(), job->owner(), ending.facts->samples);
      }
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

void JobManager::on_failed(const std::string& id, const std::string& error) {
  const std::shared_ptr<Job> job = find(id);
  if (!job) return;
  {
    std::lock_guard lock(job->mu_);
    if (is_terminal(job->status_) || job->finishing_) return;
    // The partial pass was dropped; the runner is at its last pass boundary.
    job->runner_->fail(error);
    job->finish_locked(unix_now());
  }
  if (recorder_.persist(*job, true)) release_state(*job);
  job_left_scheduler(*job);
}

void JobManager::on_cancelled(const std::string& id) {
  const std::shared_ptr<Job> job = find(id);
  if (!job) return;
  {
    std::lock_guard lock(job->mu_);
    if (is_terminal(job->status_) || job->finishing_) return;
    // The partial pass was dropped; the runner is at its last pass boundary.
    job->runner_->cancel();
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
    const auto check_room = [&] {
      if (is_terminal(job->status_)) admission_.check_room(who);
    };
    bool from_disk = false;  // read back for this extend: dropped again if it is refused
    if (!job->runner_ && loaded && is_terminal(job->status_)) {
      job->runner_ = std::move(loaded);
      from_disk = true;
    }
    if (!is_terminal(job->status_)) {
      throw JobError(JobError::Kind::conflict,
                     fmt::format("job {} is still {}; extend a finished job", id, job_status_name(job->status_)));
    }
    if (job->status_ == JobStatus::failed || !job->runner_ || !job->def_) {
      if (from_disk) job->runner_.reset();
      throw JobError(JobError::Kind::conflict,
                     fmt::format("job {} failed{}; a failed job cannot be extended", id,
                                 job->error_.empty() ? "" : ": " + job->error_));
    }
    JobRunner trial = *job->runner_;  // leave the job untouched if the rule is refused
    trial.extend(rule);
    if (trial.finished()) {
      if (from_disk) job->runner_.reset();
      throw JobError(JobError::Kind::conflict,
                     fmt::format("the new rule is already met by job {} ({}); ask for more", id,
                                 stop_reason_name(trial.stop_reason())));
    }
    try {
      check_room();
    } catch (const JobError&) {
      if (from_disk) job->runner_.reset();
      throw;
    }
    job->reopen_locked(std::move(trial), from_disk);
    if (!from_disk) admission_.charge(*job);
  }
  results_.erase(id);  // its result changes
  log::job(log::Level::info, id, "extended; queued again");
  recorder_.persist(*job, false);
  std::lock_guard lock(mu_);
  admission_.enqueue(job);
  start_queued_locked();
  return job;
}

// ---------------------------------------------------------------- recovery, shutdown

void JobManager::recover() {
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
      const uint64_t bytes = job->def_ ? Admission::memory_bytes(*job->def_) : 0;
      if (job->def_) job->cache_key_ = ResultCache::key_of(job->spec(), job->def_->seed());
      if (job->status_ == JobStatus::succeeded && answers_its_spec(job->def_.get(), job->facts_.get())) {
        results_.add(job->cache_key_, job->id(), job->owner(), job->facts_->samples);
      }
      admission_.track(*job, bytes, UINT64_MAX);
      if (job->runner_ && !is_terminal(job->status_) && !admission_.fits(bytes)) {
        // Resumed beyond the memory budget: its state goes back to disk until it starts.
        job->park_locked();
      }
      if (job->runner_) admission_.charge(*job);  // resumed from a checkpoint: its state is in memory
      if (!is_terminal(job->status_)) {
        job->status_ = JobStatus::queued;
        admission_.enqueue(job);
        ++resumed;
        log::job(log::Level::info, job->id(), "resumes from its checkpoint ({} samples)",
                 job->runner_ ? job->runner_->state().samples : 0);
      }
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
  results_.erase(id);
  recorder_.removed(*job);
  job->events_.close();
  log::job(log::Level::info, id, "deleted");
}

std::vector<std::string> JobManager::apply_retention() {
  if (!retention_.policy().any()) return {};
  std::vector<JobRetention::Finished> done;
  for (const auto& job : list()) {
    std::lock_guard jl(job->mu_);
    if (is_terminal(job->status_)) done.push_back({job->id(), job->finished_at_, job->seq(), job->stored_bytes_});
  }
  std::vector<std::string> removed;
  for (const JobRetention::Retire& r : retention_.select(std::move(done), unix_now())) {
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
    if (unfinished) {
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
  for (JobStatus st : {JobStatus::queued, JobStatus::running, JobStatus::succeeded, JobStatus::failed,
                       JobStatus::cancelled}) {
    s.jobs_by_state[std::string(job_status_name(st))] = 0;
  }
  std::vector<std::shared_ptr<Job>> jobs;
  {
    std::lock_guard lock(mu_);
    jobs = order_;
    s.queue_depth = admission_.queued();
  }
  const ExecutorStats es = executor_->stats();
  // The scaling signal: the jobs' own forecasts (Job::forecast_locked), a running job on
  // its share of the workers.
  size_t running = 0;
  for (const auto& j : jobs) {
    std::lock_guard jl(j->mu_);
    if (j->status_ == JobStatus::running) ++running;
  }
  const double share = running > 0 ? static_cast<double>(es.workers) / static_cast<double>(running) : 1.0;
  for (const auto& j : jobs) {
    std::lock_guard jl(j->mu_);
    s.jobs_by_state[std::string(job_status_name(j->status_))]++;
    if (j->status_ == JobStatus::running && j->runner_) s.samples_per_second += j->runner_->samples_per_second();
    j->forecast_locked(share, s.predicted_cpu_seconds_running, s.predicted_cpu_seconds_queued);
  }
  s.samples_total = es.samples_done;
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
    s.preemptions = preemptions_;
    s.result_cache_hits = results_.hits();
    s.result_cache_misses = results_.misses();
  }
  s.finished_cache_bytes = finished_.bytes();
  s.state_loads = finished_.loads();
  return s;
}

}  // namespace tally
