#include "server/jobs/job_manager.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <chrono>
#include <random>
#include <set>

#include "common/engine/checkpoint.hpp"
#include "common/log/log.hpp"
#include "common/protocol/job_json.hpp"
#include "common/protocol/spec_reader.hpp"
#include "server/executor/in_process_executor.hpp"

namespace tally {

using nlohmann::json;

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

// The runner's next pass for an executor, with the one after it when that can be
// planned already (JobRunner::plan_ahead). Empty when the job is finished.
PassWork plan_next(JobRunner& r) {
  PassWork w;
  w.pass = r.state().passes;
  w.blocks = r.plan_pass();
  w.groups = r.result_groups();
  w.pass_input = r.pass_input();
  if (w.empty()) return w;
  bool ahead_followed = false;
  if (auto blocks = r.plan_ahead(&ahead_followed)) {
    auto ahead = std::make_shared<PassWork>();
    ahead->pass = w.pass + 1;
    ahead->followed = ahead_followed;
    w.followed = true;
    ahead->blocks = std::move(*blocks);
    ahead->groups = result_groups(ahead->blocks, r.kernel().schedule().group_blocks);
    w.ahead = std::move(ahead);
  }
  return w;
}

JobStatus status_of(const JobRunner& r) {
  switch (r.stop_reason()) {
    case StopReason::none: return JobStatus::running;
    case StopReason::cancelled: return JobStatus::cancelled;
    case StopReason::failed: return JobStatus::failed;
    default: return JobStatus::succeeded;
  }
}

}  // namespace

JobSnapshot Job::snapshot_locked(bool with_runner) const {
  JobSnapshot s;
  s.id = id_;
  s.seq = seq_;
  s.priority = priority_;
  s.owner = owner_;
  s.spec = spec_;
  s.created_at = created_at_;
  s.started_at = started_at_;
  s.finished_at = finished_at_;
  s.status = status_;
  s.error = error_;
  s.version = version_;
  s.def = def_;
  s.final_result = final_result_;
  // A running job's status may lag its runner by the pass being published (built
  // without the lock in on_pass_done) rather than be rebuilt here, on an I/O thread.
  if (engine_ && (engine_version_ == version_ || status_ == JobStatus::running)) s.engine = engine_;
  s.last_event_id = events_.last_id();
  if (!runner_) {
    published_.reset();
    s.facts = facts_;
    return s;
  }
  // The documents need only the runner's figures: a running job's come from its pass
  // boundary's views, a finished one's from what finish kept (facts_, final_result_).
  if (!with_runner) {
    if (status_ == JobStatus::running && s.engine && live_facts_) {
      auto f = std::make_shared<RunFacts>(*live_facts_);
      f->rule = runner_->rule();  // extend changes it between passes
      s.facts = std::move(f);
      return s;
    }
    if (is_terminal(status_) && facts_ && final_result_) {
      s.facts = facts_;
      return s;
    }
  }
  // The runner changes in place at pass boundaries: readers get a copy made once
  // per version, which no one mutates afterwards.
  if (published_version_ != version_) {
    published_ = std::make_shared<const JobRunner>(*runner_);
    published_version_ = version_;
  }
  s.runner = published_;
  return s;
}

JobManager::JobManager(ManagerConfig config, JobStore& store, JobCompiler compiler)
    : config_(std::move(config)), compiler_(std::move(compiler)),
      recorder_(store, compiler_, config_.limits, config_.event_buffer), store_(store) {
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
  retention_.request_stop();
  if (retention_.joinable()) retention_.join();
  executor_->stop();
  recorder_.flush_finals();  // their callbacks use this manager
}

uint64_t JobManager::state_bytes(const JobDefinition& def) {
  const Kernel& k = *def.kernel();
  return 2 * (static_cast<uint64_t>(k.channel_count()) * sizeof(Tally) +
              static_cast<uint64_t>(k.partition_count()) * sizeof(uint64_t));
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
  if (const ExecutorStats es = executor_->stats(); es.blocks_by_job.count(job.id_)) {
    const auto& b = es.blocks_by_job.at(job.id_);
    note.has_blocks = true;
    note.pending = b.pending;
    note.in_flight = b.in_flight;
    note.redelivered = b.redelivered;
  }
  std::lock_guard lock(job.mu_);
  JobSnapshot s = job.snapshot_locked(of == SnapshotOf::state);
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

std::shared_ptr<const std::string> JobManager::watch_progress_locked(const Job& job) {
  if (!job.runner_) return nullptr;
  // While a pass is being published (on_pass_done builds it without the lock) the
  // previous pass's progress serves: the new one follows as a live event.
  // No progress published yet for a pass being published (the first one): none serves.
  if (job.publishing_ && !job.watch_progress_) return nullptr;
  const bool publishing = job.status_ == JobStatus::running && job.watch_progress_;
  if (!job.watch_progress_ || (job.watch_progress_version_ != job.version_ && !publishing)) {
    job.watch_progress_ = std::make_shared<const std::string>(dump(progress_event_json(*job.runner_)));
    job.watch_progress_version_ = job.version_;
  }
  return job.watch_progress_;
}

namespace {
json state_event_of(JobStatus status, const JobRunner* runner, const RunFacts* facts,
                    const std::string& error, bool end) {
  return runner ? state_event_json(status, runner, error, end) : state_event_json(status, facts, error, end);
}
}  // namespace

std::vector<Event> JobManager::watch_snapshot(const Job& job) const {
  std::lock_guard lock(job.mu_);
  const uint64_t id = job.events_.last_id();  // every append happens under job.mu_
  std::vector<Event> out;
  // A job whose state is not in memory (queued, or finished and on disk) shows the
  // figures kept when it left (RunFacts): the same bytes the runner would give.
  const RunFacts* facts = job.facts_.get();
  out.push_back(Event{id, "state", dump(state_event_of(job.status_, job.runner_.get(), facts, job.error_, false))});
  if (job.runner_ && job.runner_->state().passes > 0) {
    // Built on a worker thread at the pass boundary; only a rare transition
    // (start, cancel of a queued job, extend) leaves it to be built here.
    if (auto progress = watch_progress_locked(job)) out.push_back(Event{id, "progress", *progress});
  } else if (!job.runner_ && facts && !facts->progress_event.empty()) {
    out.push_back(Event{id, "progress", facts->progress_event});
  }
  if (is_terminal(job.status_)) {
    out.push_back(Event{id, "end", dump(state_event_of(job.status_, job.runner_.get(), facts, job.error_, true))});
  }
  return out;
}

JobStatus JobManager::status(const Job& job) const {
  std::lock_guard lock(job.mu_);
  return job.status_;
}

// ---------------------------------------------------------------- lifecycle


void JobManager::publish_state_locked(Job& job) {
  job.events_.append("state",
                     dump(state_event_of(job.status_, job.runner_.get(), job.facts_.get(), job.error_, false)));
}

JobEnding JobManager::ending_locked(const Job& job, double now, std::optional<JobStatus> status,
                                    const FinishViews* views) {
  JobEnding e;
  e.status = status ? *status : job.runner_ ? status_of(*job.runner_) : JobStatus::failed;
  if (e.status == JobStatus::running) e.status = JobStatus::succeeded;  // plan_pass had nothing left
  e.error = job.error_;
  if (job.runner_ && job.runner_->error_message() && e.error.empty()) e.error = *job.runner_->error_message();
  e.finished_at = now;
  if (views && job.runner_) {
    e.final_result = views->final_result;
    e.facts = views->facts;
  } else {
    e.final_result = job.runner_ && job.def_ ? std::make_shared<const json>(engine_json(*job.def_, *job.runner_))
                                             : std::make_shared<const json>(json::object());
    // What the views show once the state leaves memory (release_state).
    e.facts = job.runner_ ? std::make_shared<const RunFacts>(run_facts(*job.runner_)) : job.facts_;
  }
  return e;
}

void JobManager::finish_locked(Job& job, double now, std::optional<JobStatus> status, const FinishViews* views) {
  end_locked(job, ending_locked(job, now, status, views), views);
}

void JobManager::end_locked(Job& job, const JobEnding& e, const FinishViews* views) {
  job.status_ = e.status;
  job.error_ = e.error;
  job.finished_at_ = e.finished_at;
  job.final_result_ = e.final_result;
  job.facts_ = e.facts;
  job.finishing_ = false;
  job.live_facts_.reset();
  job.version_++;
  if (views && job.runner_ && job.runner_->state().passes > 0) {
    job.watch_progress_ = views->progress;
    job.watch_progress_version_ = job.version_;
  } else if (job.runner_ && job.runner_->state().passes > 0) {
    watch_progress_locked(job);
  }
  // With views, the events read the facts built from the runner (the same figures).
  const JobRunner* runner = views ? nullptr : job.runner_.get();
  job.events_.append("state", dump(state_event_of(job.status_, runner, job.facts_.get(), job.error_, false)));
  job.events_.append("end", dump(state_event_of(job.status_, runner, job.facts_.get(), job.error_, true)));
  log::job(job.status_ == JobStatus::failed ? log::Level::warn : log::Level::info, job.id_, "{}{}{}",
           job_status_name(job.status_),
           job.runner_ ? fmt::format(" ({}, {} samples)", stop_reason_name(job.runner_->stop_reason()),
                                     job.runner_->state().samples)
                       : std::string(),
           job.error_.empty() ? std::string() : ": " + job.error_);
}

void JobManager::check_memory(const json& spec, const JobLimits& limits, const JobDefinition& def) const {
  const uint64_t need = state_bytes(def);
  if (config_.memory_budget == 0 || need <= config_.memory_budget) return;
  const auto mib = [](uint64_t b) { return fmt::format("{:.1f} MiB", static_cast<double>(b) / (1 << 20)); };
  const std::string why = fmt::format("the job needs {} of memory for its state, more than the server's memory "
                                      "budget of {} (--memory-budget)",
                                      mib(need), mib(config_.memory_budget));
  // The kind's own channel limit names the field: compile again with the channels
  // the budget allows.
  JobLimits fit = limits;
  fit.max_channels = std::min<size_t>(limits.max_channels, config_.memory_budget / (2 * sizeof(Tally)));
  try {
    compiler_(spec, fit);
  } catch (const SpecError& e) {
    throw SpecError(e.pointer(), fmt::format("{}: {}", why, e.detail()));
  }
  throw SpecError("", why);
}

std::shared_ptr<Job> JobManager::submit(const json& spec, int priority, const Submitter& who) {
  const JobLimits& limits = who.limits ? *who.limits : config_.limits;
  std::shared_ptr<const JobDefinition> def = compiler_(spec, limits);  // throws SpecError
  // The state is allocated when the job starts; a job whose state could never fit
  // the budget is refused now.
  check_memory(spec, limits, *def);
  const uint64_t need = state_bytes(*def);
  std::shared_ptr<Job> job;
  {
    std::lock_guard lock(mu_);
    if (shutting_down_) throw JobError(JobError::Kind::unavailable, "the server is shutting down");
    if (queue_.size() >= config_.max_queued && running_ >= config_.max_running) {
      throw JobError(JobError::Kind::queue_full,
                     fmt::format("the job queue is full ({} queued, {} running); retry later", queue_.size(), running_));
    }
    if (who.max_queued != UINT64_MAX || who.max_running != UINT64_MAX) {
      const auto r = running_by_owner_.find(who.owner);
      const uint64_t running = r == running_by_owner_.end() ? 0 : r->second;
      const auto queued = static_cast<uint64_t>(
          std::count_if(queue_.begin(), queue_.end(), [&](const auto& j) { return j->owner() == who.owner; }));
      const bool would_wait = running >= who.max_running || running_ >= config_.max_running;
      if (would_wait && queued >= who.max_queued) {
        throw JobError(JobError::Kind::quota,
                       fmt::format("quota max_queued_jobs: \"{}\" already has {} queued and {} running jobs "
                                   "(max_queued_jobs {}, max_running_jobs {})",
                                   who.owner, queued, running, who.max_queued, who.max_running));
      }
    }
    job = std::make_shared<Job>(new_job_id(), next_seq_++, spec, clamp_priority(priority), unix_now(), epoch_,
                                config_.event_buffer, who.owner);
    job->owner_max_running_ = who.max_running;
    job->state_bytes_ = need;
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
    queue_.push_back(job);
    start_queued_locked();
  }
  return job;
}

void JobManager::start_queued_locked() {
  while (running_ < config_.max_running && !queue_.empty() && !shutting_down_) {
    std::shared_ptr<Job> job = next_to_start_locked();
    if (!job) break;
    queue_.erase(std::find(queue_.begin(), queue_.end(), job));
    PassWork pass;
    ExecutorJob ej;
    {
      std::lock_guard jl(job->mu_);
      if (job->status_ != JobStatus::queued) continue;
      if (!job->runner_) {
        // The state is allocated now, not at submission.
        if (!job->def_) continue;
        const StopRule rule = job->facts_ ? job->facts_->rule : job->def_->stop_rule();
        job->runner_ = std::make_unique<JobRunner>(job->def_->kernel(), rule, job->caps_);
        job->facts_.reset();
      }
      if (!job->charged_) {
        job->charged_ = true;
        memory_used_ += job->state_bytes_;
      }
      job->status_ = JobStatus::running;
      if (job->started_at_ <= 0) job->started_at_ = unix_now();
      // Where the job starts is durable already (its spec, or the checkpoint it resumes
      // from): the first checkpoint is due one interval from now, not at the first pass
      // boundary, where it would save little and copy the whole state (an image's every
      // pixel) on the thread that publishes the next pass.
      job->last_checkpoint_ = std::chrono::steady_clock::now();
      job->version_++;
      publish_state_locked(*job);
      if (job->runner_->state().passes == 0) {
        // The documents' views of a fresh state (no pass over data: cheap), so status
        // reads copy no runner before the first pass either. A job resumed from a
        // checkpoint has them from its first pass on (until then a read copies it).
        job->engine_ = std::make_shared<const json>(engine_json(*job->def_, *job->runner_));
        job->engine_version_ = job->version_;
        job->live_facts_ = std::make_shared<const RunFacts>(live_run_facts(*job->runner_));
      }
      pass = plan_next(*job->runner_);
      if (pass.empty()) {
        finish_locked(*job, unix_now());
      } else {
        ej.id = job->id();
        ej.kernel = job->def_->kernel();
        ej.spec_json = job->spec().dump();
        ej.epoch = epoch_;
        ej.priority = job->priority();
        ej.owner = job->owner();
      }
    }
    if (pass.empty()) {
      // Nothing to run (restored already complete): store the final state.
      recorder_.persist(*job, true);
      continue;
    }
    log::job(log::Level::debug, job->id(), "running");
    ++running_;
    ++running_by_owner_[job->owner()];
    executor_->add(std::move(ej), std::move(pass));
  }
}

std::shared_ptr<Job> JobManager::next_to_start_locked() {
  // Highest priority first, then submission order; skipping owners at their
  // running-jobs quota. The first in that order waits while its state does not fit
  // the memory budget (no smaller job overtakes it), except that jobs already
  // holding their state (resumed or extended) may start: they need nothing more.
  const auto before = [](const std::shared_ptr<Job>& a, const std::shared_ptr<Job>& b) {
    return a->priority() != b->priority() ? a->priority() > b->priority() : a->seq() < b->seq();
  };
  std::shared_ptr<Job> best, best_charged;
  for (const auto& c : queue_) {
    const auto r = running_by_owner_.find(c->owner());
    if (r != running_by_owner_.end() && r->second >= c->owner_max_running_) continue;
    if (!best || before(c, best)) best = c;
    if (c->charged_ && (!best_charged || before(c, best_charged))) best_charged = c;
  }
  if (!best) return nullptr;
  // With nothing in memory a job always starts (the budget may have shrunk since it
  // was admitted).
  if (best->charged_ || config_.memory_budget == 0 || memory_used_ == 0 ||
      memory_used_ + best->state_bytes_ <= config_.memory_budget) {
    return best;
  }
  return best_charged;
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
  if (job.charged_) {
    job.charged_ = false;
    memory_used_ -= job.state_bytes_;
  }
  start_queued_locked();  // the memory freed may let a waiting job start
}

void JobManager::job_left_scheduler(const Job& job) {
  std::lock_guard lock(mu_);
  if (running_ > 0) --running_;
  if (auto it = running_by_owner_.find(job.owner()); it != running_by_owner_.end() && --it->second == 0) {
    running_by_owner_.erase(it);
  }
  start_queued_locked();
}

namespace {

// The pass's tile events of an image job (one per tile refined in the pass).
std::vector<std::string> tile_events(const ImageSource* img, const std::vector<Block>& blocks, uint64_t pass) {
  std::vector<std::string> out;
  if (!img) return out;
  std::set<uint32_t> tiles;
  for (const Block& b : blocks) tiles.insert(img->tile_of_partition(b.partition));
  for (uint32_t t : tiles) {
    const TileRect rc = img->tile_rect(t);
    out.push_back(dump(json{{"tile", t}, {"x", rc.x}, {"y", rc.y}, {"w", rc.w}, {"h", rc.h}, {"pass", pass}}));
  }
  return out;
}

}  // namespace

PassWork JobManager::on_pass_done(const std::string& id, const PassWork& done, std::vector<BlockResult>&& results,
                                  double wall) {
  const std::shared_ptr<Job> job = find(id);
  if (!job) return {};
  const std::vector<Block>& blocks = done.blocks;
  PassWork next;
  bool finished = false, checkpoint = false, cancel_now = false;
  uint64_t version = 0;
  using Clock = std::chrono::steady_clock;
  const auto t0 = Clock::now();
  Clock::time_point t_locked, t_committed;
  {
    std::lock_guard lock(job->mu_);
    t_locked = Clock::now();
    JobRunner& r = *job->runner_;
    try {
      r.commit_groups(std::move(results), wall);
    } catch (const std::exception& e) {
      log::job(log::Level::error, job->id(), "committing pass {} failed: {}", done.pass, e.what());
      r.fail(fmt::format("internal error committing a pass: {}", e.what()));
    }
    t_committed = Clock::now();
    job->version_++;
    version = job->version_;
    job->publishing_ = true;  // until this pass's progress event is in the log (below)
    cancel_now = job->cancel_requested_ && !r.finished();
    if (!cancel_now && !r.finished()) next = plan_next(r);
    finished = cancel_now || r.finished() || next.empty();
    if (finished) next = PassWork{};
    const auto now = std::chrono::steady_clock::now();
    if (finished || now - job->last_checkpoint_ >= std::chrono::duration<double>(config_.checkpoint_interval_s)) {
      job->last_checkpoint_ = now;
      checkpoint = true;
    }
  }
  // The heavy views of the pass (progress event, status JSON, tile events, and for the
  // last pass the final result and facts: passes over every pixel of an image) are built
  // here without the job's lock, so status GETs and watchers never wait for them. The
  // runner is not mutated meanwhile: only this callback, at a pass boundary, changes it
  // (the cancel below under the lock), and the executors call cancelled/failed for a
  // job only once its pass_done has returned (the next pass starts after that).
  const JobRunner& r = *job->runner_;
  const auto t_views = Clock::now();
  auto progress = std::make_shared<const std::string>(dump(progress_event_json(r)));
  std::vector<std::string> tiles = tile_events(job->def_->image(), blocks, r.state().passes);
  std::shared_ptr<const json> engine;
  std::shared_ptr<const RunFacts> live;
  FinishViews views;
  JobEnding ending;
  if (finished) {
    if (cancel_now) {
      std::lock_guard lock(job->mu_);
      job->runner_->cancel();  // takes effect at this boundary
    }
    views.progress = cancel_now ? std::make_shared<const std::string>(dump(progress_event_json(r))) : progress;
    views.final_result = std::make_shared<const json>(job->def_ ? engine_json(*job->def_, r) : json::object());
    views.facts = std::make_shared<const RunFacts>(run_facts(r, views.progress.get()));
  } else {
    engine = job->def_ ? std::make_shared<const json>(engine_json(*job->def_, r)) : nullptr;
    live = std::make_shared<const RunFacts>(live_run_facts(r));
  }
  const auto t_publish = Clock::now();
  {
    std::lock_guard lock(job->mu_);
    job->events_.append("progress", *progress);
    for (std::string& t : tiles) job->events_.append("tile", std::move(t));
    job->watch_progress_ = std::move(progress);
    job->watch_progress_version_ = version;
    job->publishing_ = false;
    if (finished) {
      // Its ending is stored before it is published (below): until then the job reads
      // as running, with the last pass's figures.
      ending = ending_locked(*job, unix_now(), std::nullopt, &views);
      job->finishing_ = true;
      job->engine_ = views.final_result;
      job->engine_version_ = version;
      job->live_facts_ = views.facts;
    } else {
      job->engine_ = std::move(engine);
      job->engine_version_ = version;
      job->live_facts_ = std::move(live);
    }
  }
  const auto t_published = Clock::now();
  auto ms = [](Clock::time_point a, Clock::time_point b) { return std::chrono::duration<double, std::milli>(b - a).count(); };
  log::job(log::Level::debug, job->id(),
           "pass {} boundary: lock wait {:.3f} ms, commit {:.3f} ms, plan {:.3f} ms, views {:.3f} ms, publish {:.3f} ms",
           done.pass, ms(t0, t_locked), ms(t_locked, t_committed), ms(t_committed, t_views), ms(t_views, t_publish),
           ms(t_publish, t_published));
  // A periodic checkpoint is written on the recorder's thread while the next pass runs.
  // The last save (the ending and the final checkpoint) on its finisher thread: this
  // thread goes on at once (a worker; in cluster mode the coordinator), the job reads
  // as finished once it is stored, and its state then leaves memory (if the save
  // failed, it stays until a retried save succeeds; the image routes read it from memory).
  if (checkpoint && !finished) recorder_.checkpoint_later(job);
  if (finished) {
    auto shown = std::make_shared<const FinishViews>(std::move(views));
    recorder_.save_final_later(job, ending, [this, job, ending, shown](bool stored) {
      {
        std::lock_guard lock(job->mu_);
        end_locked(*job, ending, shown.get());  // its events, then state and end, under one lock
      }
      if (stored) {
        release_state(*job);
      } else {
        recorder_.persist(*job, true);  // retried until stored, now as it reads
      }
    });
    job_left_scheduler(*job);
  }
  return next;
}

void JobManager::on_failed(const std::string& id, const std::string& error) {
  const std::shared_ptr<Job> job = find(id);
  if (!job) return;
  {
    std::lock_guard lock(job->mu_);
    if (is_terminal(job->status_) || job->finishing_) return;
    // The partial pass was dropped; the runner is at its last pass boundary.
    job->runner_->fail(error);
    finish_locked(*job, unix_now());
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
    finish_locked(*job, unix_now());
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
      queue_.erase(std::remove(queue_.begin(), queue_.end(), job), queue_.end());
      if (job->runner_) {
        job->runner_->cancel();
      } else {
        // Never started: no state, the facts say it was cancelled.
        RunFacts f = job->facts_ ? *job->facts_ : RunFacts{};
        f.stop_reason = StopReason::cancelled;
        job->facts_ = std::make_shared<const RunFacts>(std::move(f));
      }
      finish_locked(*job, unix_now(), JobStatus::cancelled);
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

std::shared_ptr<Job> JobManager::extend(const std::string& id, const StopRule& rule) {
  std::shared_ptr<Job> job = find(id);
  if (!job) throw JobError(JobError::Kind::not_found, fmt::format("no job with id \"{}\"", id));
  // A finished job's state is on disk: read it back (outside the locks) to go on.
  std::unique_ptr<JobRunner> loaded;
  if (const JobSnapshot s = snapshot(*job, SnapshotOf::state);
      is_terminal(s.status) && s.status != JobStatus::failed && !s.runner && s.def && s.facts) {
    std::optional<std::string> cp;
    try {
      cp = store_.load_checkpoint(id);
      loaded = cp ? std::make_unique<JobRunner>(s.def->kernel(), s.facts->rule, job->caps_, decode_checkpoint(*cp))
                  : std::make_unique<JobRunner>(s.def->kernel(), s.facts->rule, job->caps_);
    } catch (const std::exception& e) {
      log::job(log::Level::warn, id, "reading the stored state to extend failed: {}", e.what());
      throw JobError(JobError::Kind::conflict, fmt::format("job {}'s stored state cannot be read: {}", id, e.what()));
    }
  }
  {
    std::lock_guard lock(mu_);
    if (shutting_down_) throw JobError(JobError::Kind::unavailable, "the server is shutting down");
    std::lock_guard jl(job->mu_);
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
    *job->runner_ = std::move(trial);
    job->facts_.reset();
    if (!job->charged_) {
      job->charged_ = true;
      memory_used_ += job->state_bytes_;
    }
    job->status_ = JobStatus::queued;
    job->cancel_requested_ = false;
    job->error_.clear();
    job->finished_at_ = 0;
    job->final_result_.reset();
    job->engine_.reset();
    job->live_facts_.reset();
    job->version_++;
    publish_state_locked(*job);
  }
  log::job(log::Level::info, id, "extended; queued again");
  recorder_.persist(*job, false);
  std::lock_guard lock(mu_);
  queue_.push_back(job);
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
      if (job->def_) job->state_bytes_ = state_bytes(*job->def_);
      if (job->runner_) {  // resumed from a checkpoint: its state is in memory
        job->charged_ = true;
        memory_used_ += job->state_bytes_;
      }
      if (!is_terminal(job->status_)) {
        job->status_ = JobStatus::queued;
        queue_.push_back(job);
        ++resumed;
        log::job(log::Level::info, job->id(), "resumes from its checkpoint ({} samples)",
                 job->runner_ ? job->runner_->state().samples : 0);
      }
    }
    if (!rec.jobs.empty()) log::info("recovered {} jobs ({} resume), epoch {}", rec.jobs.size(), resumed, epoch_);
    start_queued_locked();
  }
  apply_retention();
  if (config_.retain_max_age_s > 0 || config_.retain_max_jobs > 0 || config_.retain_max_bytes > 0) {
    retention_ = std::jthread([this](std::stop_token st) { retention_loop(st); });
  }
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
    if (job->charged_) {
      job->charged_ = false;
      memory_used_ -= job->state_bytes_;
    }
    ++jobs_removed_;
  }
  {
    std::lock_guard lock(cache_mu_);
    for (auto it = cache_.begin(); it != cache_.end();) {
      if (it->id == id) {
        cache_bytes_ -= it->bytes;
        it = cache_.erase(it);
      } else {
        ++it;
      }
    }
  }
  {
    // A save may still be in flight or to come (a retry of a failed final save runs
    // after the job reads as finished): mark the job removed under its save lock (a
    // later save then writes nothing) and delete the row once more, in case a save
    // wrote it back meanwhile. Only the save lock is held here
    // (the pass callback takes it under the manager's lock: never the other way round).
    std::lock_guard save_lock(job->save_mu_);
    job->removed_ = true;
    try {
      if (store_.remove(id)) log::job(log::Level::debug, id, "a save in flight had written the row back: deleted again");
    } catch (const std::exception& e) {
      log::job(log::Level::warn, id, "deleting the job's row again failed ({}): it may come back after a restart",
               e.what());
    }
  }
  job->events_.close();
  log::job(log::Level::info, id, "deleted");
}

std::vector<std::string> JobManager::apply_retention() {
  const ManagerConfig& c = config_;
  if (c.retain_max_age_s <= 0 && c.retain_max_jobs == 0 && c.retain_max_bytes == 0) return {};
  struct Finished {
    std::string id;
    double finished_at;
    int64_t seq;
    uint64_t bytes;
  };
  std::vector<Finished> done;
  for (const auto& job : list()) {
    std::lock_guard jl(job->mu_);
    if (is_terminal(job->status_)) done.push_back({job->id(), job->finished_at_, job->seq(), job->stored_bytes_});
  }
  std::sort(done.begin(), done.end(), [](const Finished& a, const Finished& b) {
    return a.finished_at != b.finished_at ? a.finished_at < b.finished_at : a.seq < b.seq;
  });
  size_t count = done.size();
  uint64_t bytes = 0;
  for (const Finished& f : done) bytes += f.bytes;
  const double now = unix_now();
  std::vector<std::string> removed;
  for (const Finished& f : done) {  // oldest first
    std::string why;
    if (c.retain_max_age_s > 0 && now - f.finished_at > c.retain_max_age_s) {
      why = fmt::format("finished {:.0f} s ago (--retain-max-age {} s)", now - f.finished_at, c.retain_max_age_s);
    } else if (c.retain_max_jobs > 0 && count > c.retain_max_jobs) {
      why = fmt::format("{} finished jobs (--retain-max-jobs {})", count, c.retain_max_jobs);
    } else if (c.retain_max_bytes > 0 && bytes > c.retain_max_bytes) {
      why = fmt::format("finished jobs take {} bytes (--retain-max-bytes {})", bytes, c.retain_max_bytes);
    } else {
      break;  // every later job is newer, and the totals only shrink
    }
    --count;
    bytes -= f.bytes;
    try {
      remove(f.id);
      log::job(log::Level::info, f.id, "deleted by retention: {}", why);
      removed.push_back(f.id);
    } catch (const JobError& e) {
      // Extended or deleted meanwhile: it is no longer a finished job to retire.
      log::job(log::Level::debug, f.id, "retention skipped it: {}", e.what());
    }
  }
  if (!removed.empty()) log::info("retention deleted {} finished jobs", removed.size());
  return removed;
}

void JobManager::retention_loop(std::stop_token st) {
  std::unique_lock lock(retention_mu_);
  while (!st.stop_requested()) {
    retention_cv_.wait_for(lock, st, std::chrono::duration<double>(config_.retention_interval_s),
                           [] { return false; });
    if (st.stop_requested()) break;
    lock.unlock();
    try {
      apply_retention();
    } catch (const std::exception& e) {
      log::warn("retention failed: {}", e.what());
    }
    lock.lock();
  }
}

// ---------------------------------------------------------------- finished states

std::shared_ptr<const JobState> JobManager::state(const JobSnapshot& s) {
  if (s.runner) return std::shared_ptr<const JobState>(s.runner, &s.runner->state());
  if (!is_terminal(s.status) || !s.def || !s.facts) return nullptr;
  {
    std::lock_guard lock(cache_mu_);
    for (auto it = cache_.begin(); it != cache_.end(); ++it) {
      if (it->id == s.id && it->version == s.version) {
        cache_.splice(cache_.begin(), cache_, it);
        return cache_.front().state;
      }
    }
  }
  return load_finished_state(s);
}

std::shared_ptr<const JobState> JobManager::load_finished_state(const JobSnapshot& s) {
  std::optional<std::string> cp;
  std::shared_ptr<const JobState> st;
  try {
    cp = store_.load_checkpoint(s.id);
    if (!cp) return nullptr;
    st = std::make_shared<const JobState>(decode_checkpoint(*cp));
  } catch (const std::exception& e) {
    log::job(log::Level::warn, s.id, "reading the finished job's state from the store failed: {}", e.what());
    return nullptr;
  }
  const Kernel& k = *s.def->kernel();
  if (st->channels.size() != k.channel_count() || st->partition_samples.size() != k.partition_count()) {
    log::job(log::Level::warn, s.id, "the stored state does not match the job ({} channels, expected {})",
             st->channels.size(), k.channel_count());
    return nullptr;
  }
  const uint64_t bytes = state_bytes(*s.def) / 2;
  std::lock_guard lock(cache_mu_);
  ++state_loads_;
  for (auto it = cache_.begin(); it != cache_.end();) {  // an older version of the same job
    if (it->id == s.id) {
      cache_bytes_ -= it->bytes;
      it = cache_.erase(it);
    } else {
      ++it;
    }
  }
  if (bytes <= config_.finished_cache_bytes) {
    cache_.push_front(CachedState{s.id, s.version, st, bytes});
    cache_bytes_ += bytes;
    while (cache_bytes_ > config_.finished_cache_bytes) {
      cache_bytes_ -= cache_.back().bytes;
      cache_.pop_back();
    }
  }
  return st;
}

void JobManager::shutdown() {
  {
    std::lock_guard lock(mu_);
    if (shutting_down_) return;
    shutting_down_ = true;
  }
  retention_.request_stop();
  if (retention_.joinable()) retention_.join();
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
    s.queue_depth = queue_.size();
  }
  for (const auto& j : jobs) {
    std::lock_guard jl(j->mu_);
    s.jobs_by_state[std::string(job_status_name(j->status_))]++;
    if (j->status_ == JobStatus::running && j->runner_) s.samples_per_second += j->runner_->samples_per_second();
  }
  const ExecutorStats es = executor_->stats();
  s.samples_total = es.samples_done;
  s.workers = es.workers;
  s.busy_workers = es.busy_workers;
  s.store_failures = recorder_.store_failures();
  s.store_ok = !recorder_.store_problem().has_value();
  s.cpu_seconds_by_owner = es.cpu_seconds_by_owner;
  {
    std::lock_guard lock(mu_);
    s.memory_budget = config_.memory_budget;
    s.memory_used = memory_used_;
    s.jobs_removed = jobs_removed_;
  }
  {
    std::lock_guard lock(cache_mu_);
    s.finished_cache_bytes = cache_bytes_;
    s.state_loads = state_loads_;
  }
  return s;
}

}  // namespace tally
