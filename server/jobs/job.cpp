#include "server/jobs/job.hpp"

#include <fmt/format.h>

#include <chrono>
#include <cmath>
#include <mutex>
#include <random>

#include "common/log/log.hpp"
#include "server/jobs/job_error.hpp"
#include "common/protocol/job_json.hpp"
#include "server/jobs/pass_views.hpp"

namespace tally {

double unix_now() {
  return std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
}

std::string new_job_id() {
  static std::mutex mu;
  static std::mt19937_64 rng{std::random_device{}() ^
                             static_cast<uint64_t>(std::chrono::steady_clock::now().time_since_epoch().count())};
  std::lock_guard lock(mu);
  return fmt::format("{:016x}", rng());
}

namespace {
std::string spec_text_of(const nlohmann::json& spec) {
  return spec.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
}
}  // namespace

Job::Job(std::string id, int64_t seq, nlohmann::json spec, int priority, double created_at, uint64_t epoch,
         size_t event_buffer, std::string owner)
    : id_(std::move(id)), seq_(seq), spec_(std::make_shared<const nlohmann::json>(std::move(spec))),
      spec_text_(spec_text_of(*spec_)), priority_(priority), created_at_(created_at), owner_(std::move(owner)),
      events_(epoch, event_buffer) {}

JobSnapshot Job::snapshot_locked(bool with_runner) const {
  JobSnapshot s;
  s.id = id_;
  s.seq = seq_;
  s.priority = priority();
  s.owner = owner_;
  s.cached_from = cached_from_;
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
    idle_engine_.reset();
    idle_facts_.reset();
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
    if (!is_terminal(status_) && def_) {
      // No pass views of this process at this version (resumed from a checkpoint at start,
      // or paused and queued): the documents from the runner itself, once per version. A
      // copy of the runner here (below) was a second copy of a 4K frame's state, made by
      // the first status read after a restart and kept until the job ended.
      // Not while a pass merges (merging_): the views built before it serve.
      if (!merging_ && (idle_version_ != version_ || !idle_engine_)) build_idle_views_locked();
      if (!s.engine) s.engine = idle_engine_;
      s.facts = idle_facts_ ? idle_facts_ : facts_;
      return s;
    }
  }
  // The runner changes in place at pass boundaries: readers get a copy made once
  // per version, which no one mutates afterwards (the caller holds state_mu_: no pass is
  // being merged).
  if (published_version_ != version_) {
    published_ = std::make_shared<const JobRunner>(*runner_);
    published_version_ = version_;
  }
  s.runner = published_;
  return s;
}


void Job::build_idle_views_locked() const {
  idle_engine_ = std::make_shared<const nlohmann::json>(engine_json(*def_, *runner_));
  idle_facts_ = std::make_shared<const RunFacts>(live_run_facts(*runner_));
  idle_version_ = version_;
}

// ---------------------------------------------------------------- events and ending

namespace {

std::string dump(const nlohmann::json& j) { return j.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace); }

nlohmann::json state_event_of(JobStatus status, const JobRunner* runner, const RunFacts* facts,
                              const std::string& error, bool end) {
  return runner ? state_event_json(status, runner, error, end) : state_event_json(status, facts, error, end);
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

std::shared_ptr<const std::string> Job::watch_progress_locked() const {
  if (!runner_) return nullptr;
  // While a pass is being published (on_pass_done builds it without the lock) the
  // previous pass's progress serves: the new one follows as a live event.
  // No progress published yet for a pass being published (the first one): none serves.
  if (publishing_ && !watch_progress_) return nullptr;
  if (merging_) return watch_progress_;  // the last boundary's, or none: the runner is changing
  const bool publishing = status_ == JobStatus::running && watch_progress_;
  if (!watch_progress_ || (watch_progress_version_ != version_ && !publishing)) {
    watch_progress_ = std::make_shared<const std::string>(dump(progress_event_json(*runner_)));
    watch_progress_version_ = version_;
  }
  return watch_progress_;
}

std::vector<Event> Job::watch_snapshot() const {
  std::lock_guard lock(mu_);
  const uint64_t id = events_.last_id();  // every append happens under mu_
  std::vector<Event> out;
  // A job whose state is not in memory (queued, or finished and on disk) shows the
  // figures kept when it left (RunFacts): the same bytes the runner would give.
  const RunFacts* facts = facts_.get();
  // While a pass merges, the figures of the boundary before it (live_facts_).
  const JobRunner* runner = merging_ ? nullptr : runner_.get();
  if (merging_ && live_facts_) facts = live_facts_.get();
  out.push_back(Event{id, "state", dump(state_event_of(status_, runner, facts, error_, false))});
  if (runner_ && (merging_ ? watch_progress_ != nullptr : runner_->state().passes > 0)) {
    // Built on a worker thread at the pass boundary; only a rare transition
    // (start, cancel of a queued job, extend) leaves it to be built here.
    if (auto progress = watch_progress_locked()) out.push_back(Event{id, "progress", *progress});
  } else if (!runner_ && facts && !facts->progress_event.empty()) {
    out.push_back(Event{id, "progress", facts->progress_event});
  }
  if (is_terminal(status_)) {
    out.push_back(Event{id, "end", dump(state_event_of(status_, runner_.get(), facts, error_, true))});
  }
  return out;
}

void Job::publish_state_locked() {
  events_.append("state", dump(state_event_of(status_, runner_.get(), facts_.get(), error_, false)));
}

JobEnding Job::ending_locked(double now, std::optional<JobStatus> status, const FinishViews* views) const {
  JobEnding e;
  e.status = status ? *status : runner_ ? status_of(*runner_) : JobStatus::failed;
  if (e.status == JobStatus::running) e.status = JobStatus::succeeded;  // plan_pass had nothing left
  e.error = error_;
  if (runner_ && runner_->error_message() && e.error.empty()) e.error = *runner_->error_message();
  e.finished_at = now;
  if (views && runner_) {
    e.final_result = views->final_result;
    e.facts = views->facts;
  } else {
    e.final_result = runner_ && def_ ? std::make_shared<const nlohmann::json>(engine_json(*def_, *runner_))
                                     : std::make_shared<const nlohmann::json>(nlohmann::json::object());
    // What the views show once the state leaves memory (JobManager::release_state).
    e.facts = runner_ ? std::make_shared<const RunFacts>(run_facts(*runner_)) : facts_;
  }
  return e;
}

void Job::finish_locked(double now, std::optional<JobStatus> status, const FinishViews* views) {
  end_locked(ending_locked(now, status, views), views);
}

void Job::end_locked(const JobEnding& e, const FinishViews* views) {
  status_ = e.status;
  error_ = e.error;
  finished_at_ = e.finished_at;
  final_result_ = e.final_result;
  facts_ = e.facts;
  finishing_ = false;
  live_facts_.reset();
  version_++;
  if (views && runner_ && runner_->state().passes > 0) {
    watch_progress_ = views->progress;
    watch_progress_version_ = version_;
  } else if (runner_ && runner_->state().passes > 0) {
    watch_progress_locked();
  }
  // With views, the events read the facts built from the runner (the same figures).
  const JobRunner* runner = views ? nullptr : runner_.get();
  events_.append("state", dump(state_event_of(status_, runner, facts_.get(), error_, false)));
  events_.append("end", dump(state_event_of(status_, runner, facts_.get(), error_, true)));
  log::job(status_ == JobStatus::failed ? log::Level::warn : log::Level::info, id_, "{}{}{}", job_status_name(status_),
           runner_ ? fmt::format(" ({}, {} samples)", stop_reason_name(runner_->stop_reason()), runner_->state().samples)
                   : std::string(),
           error_.empty() ? std::string() : ": " + error_);
}

// ---------------------------------------------------------------- lifecycle steps

std::optional<PassWork> Job::start_running_locked(uint64_t epoch, double now, ExecutorJob& ej) {
  if (status_ != JobStatus::queued) return std::nullopt;
  if (!runner_) {
    // The state is allocated now, not at submission.
    if (!def_) return std::nullopt;
    const StopRule rule = facts_ ? facts_->rule : def_->stop_rule();
    runner_ = std::make_unique<JobRunner>(def_->kernel(), rule, caps_);
    facts_.reset();
  }
  status_ = JobStatus::running;
  preempted_ = false;
  preempt_requested_ = false;  // a request for a run that ended otherwise
  if (started_at_ <= 0) started_at_ = now;
  // Where the job starts is durable already (its spec, or the checkpoint it resumes
  // from): the first checkpoint is due one interval from now, not at the first pass
  // boundary, where it would save little and copy the whole state (an image's every
  // pixel) on the thread that publishes the next pass.
  last_checkpoint_ = std::chrono::steady_clock::now();
  version_++;
  publish_state_locked();
  if (runner_->state().passes == 0) {
    // The documents' views of a fresh state (no pass over data: cheap), so status
    // reads copy no runner before the first pass either. A job resumed from a
    // checkpoint has them from its first pass on (until then a read copies it).
    engine_ = std::make_shared<const nlohmann::json>(engine_json(*def_, *runner_));
    engine_version_ = version_;
    live_facts_ = std::make_shared<const RunFacts>(live_run_facts(*runner_));
  }
  PassWork pass = plan_next(*runner_);
  if (pass.empty()) {
    finish_locked(now);
    return pass;
  }
  ej.id = id_;
  ej.kernel = def_->kernel();
  ej.spec_json = spec_text_;
  ej.epoch = epoch;
  ej.priority = priority();
  ej.owner = owner_;
  return pass;
}

void Job::park_locked() {
  if (!runner_) return;
  facts_ = std::make_shared<const RunFacts>(run_facts(*runner_));
  runner_.reset();
  published_.reset();
  parked_ = true;
}

uint64_t Job::pause_locked() {
  preempt_requested_ = false;
  preempted_ = true;
  status_ = JobStatus::queued;
  const uint64_t samples = runner_ ? runner_->state().samples : 0;
  engine_.reset();
  live_facts_.reset();
  version_++;
  publish_state_locked();
  events_.append("preempted", dump(nlohmann::json{{"samples", samples}}));
  return samples;
}

void Job::reopen_locked(JobRunner runner, bool park) {
  if (park) {
    // Back to disk: it holds no memory while it waits, and is charged against the
    // memory budget when it starts (read back then, with the new rule).
    facts_ = std::make_shared<const RunFacts>(run_facts(runner));
    runner_.reset();
    parked_ = true;
  } else {
    runner_ = std::make_shared<JobRunner>(std::move(runner));  // a checkpoint may still read the old one
    facts_.reset();
  }
  status_ = JobStatus::queued;
  cancel_requested_ = false;
  error_.clear();
  finished_at_ = 0;
  final_result_.reset();
  engine_.reset();
  live_facts_.reset();
  version_++;
  publish_state_locked();
}

JobSnapshot Job::snapshot(const Executor& executor, bool with_runner) const {
  // What the executor says about the job (cluster mode: why it waits, blocks pending /
  // in flight), asked before taking the job's lock (executor locks are never nested in it).
  ExecutorNote note;
  if (auto why = executor.waiting_reason(id_)) note.waiting_reason = *why;
  note.held_queued = executor.holds_queued(id_);
  if (const ExecutorStats es = executor.stats(); es.blocks_by_job.count(id_)) {
    const auto& b = es.blocks_by_job.at(id_);
    note.has_blocks = true;
    note.pending = b.pending;
    note.in_flight = b.in_flight;
    note.redelivered = b.redelivered;
  }
  // With the runner: between merges (state_mu_), since a pass merges without mu_.
  std::unique_lock between_merges(state_mu_, std::defer_lock);
  if (with_runner) between_merges.lock();
  std::lock_guard lock(mu_);
  JobSnapshot s = snapshot_locked(with_runner);
  if (preempted_ && status_ == JobStatus::queued) note.waiting_reason = "preempted";
  // Started, but nothing can compute it yet (cluster: no live worker in its pool).
  if (s.status == JobStatus::running && note.held_queued) s.status = JobStatus::queued;
  s.executor = std::move(note);
  return s;
}

bool Job::extend_locked(const StopRule& rule, std::unique_ptr<JobRunner> loaded,
                        const std::function<void()>& check_room) {
  bool from_disk = false;  // read back for this extend: dropped again if it is refused
  if (!runner_ && loaded && is_terminal(status_)) {
    runner_ = std::move(loaded);
    from_disk = true;
  }
  if (!is_terminal(status_)) {
    throw JobError(JobError::Kind::conflict,
                   fmt::format("job {} is still {}; extend a finished job", id_, job_status_name(status_)));
  }
  const auto refuse = [&](std::string why) {
    if (from_disk) runner_.reset();
    throw JobError(JobError::Kind::conflict, std::move(why));
  };
  if (status_ == JobStatus::failed || !runner_ || !def_) {
    refuse(fmt::format("job {} failed{}; a failed job cannot be extended", id_, error_.empty() ? "" : ": " + error_));
  }
  JobRunner trial = *runner_;  // leave the job untouched if the rule is refused
  trial.extend(rule);
  if (trial.finished()) {
    refuse(fmt::format("the new rule is already met by job {} ({}); ask for more", id_,
                       stop_reason_name(trial.stop_reason())));
  }
  try {
    check_room();
  } catch (const JobError&) {
    if (from_disk) runner_.reset();
    throw;
  }
  reopen_locked(std::move(trial), from_disk);
  return from_disk;
}

void Job::cancel_queued_locked(double now) {
  if (runner_) {
    runner_->cancel();
  } else {
    // Never started (or parked): no state, the facts say it was cancelled.
    RunFacts f = facts_ ? *facts_ : RunFacts{};
    f.stop_reason = StopReason::cancelled;
    facts_ = std::make_shared<const RunFacts>(std::move(f));
  }
  finish_locked(now, JobStatus::cancelled);
}

bool Job::resumed_locked(std::unique_ptr<JobRunner> runner, const std::string& error, double now) {
  loading_ = false;
  if (!runner) {
    error_ = "its stored state cannot be read back: " + error;
    finish_locked(now, JobStatus::failed);
    return false;
  }
  runner_ = std::move(runner);
  parked_ = false;
  facts_.reset();
  return true;
}

void Job::answer_locked(std::shared_ptr<const JobDefinition> def, JobCaps caps, const JobEnding& ending) {
  caps_ = caps;
  def_ = std::move(def);
  started_at_ = created_at_;
  end_locked(ending, nullptr);
}

void Job::forecast_locked(double share, double& running, double& queued) const {
  if (status_ == JobStatus::running && runner_ && !merging_) {
    // Its ETA at its current throughput, on its share of the workers (left out for the
    // moment a pass merges).
    if (const double eta = runner_->eta_seconds(); std::isfinite(eta)) running += eta * share;
  } else if (status_ == JobStatus::queued && facts_ && facts_->samples > 0 && facts_->compute_seconds > 0 &&
             facts_->rule.max_samples > facts_->samples) {
    // Ran before (paused, extended): the samples its rule still asks for, at its rate.
    const double per_sample = facts_->compute_seconds / static_cast<double>(facts_->samples);
    queued += static_cast<double>(facts_->rule.max_samples - facts_->samples) * per_sample * share;
  }
}

void Job::merge_pass(std::vector<BlockResult>&& results, double wall, uint64_t pass) {
  std::shared_ptr<JobRunner> r;  // its own reference: the merge does not rely on runner_ staying put
  {
    std::lock_guard lock(mu_);
    merging_ = true;
    r = runner_;
  }
  std::string error = std::move(stream_error_);
  stream_error_.clear();
  try {
    if (!error.empty()) {
      // A group failed to merge: the pass is not committed.
    } else if (results.empty()) {
      r->finish_pass(wall);  // streamed: every group merged already (else it throws)
    } else {
      r->commit_groups(std::move(results), wall);
    }
  } catch (const std::exception& e) {
    log::job(log::Level::error, id_, "committing pass {} failed: {}", pass, e.what());
    error = e.what();
  }
  std::lock_guard lock(mu_);
  merging_ = false;
  if (!error.empty()) r->fail(fmt::format("internal error committing a pass: {}", error));
}

void Job::merge_group(BlockResult&& result, uint64_t pass, size_t group) {
  {
    std::unique_lock gate(merge_gate_mu_);
    merge_gate_cv_.wait(gate, [&] { return !merges_held_; });
  }
  std::lock_guard state_lock(state_mu_);
  if (!stream_error_.empty()) return;  // the pass is failed already: its later groups are dropped
  std::shared_ptr<JobRunner> r;
  {
    std::lock_guard lock(mu_);
    merging_ = true;
    r = runner_;
  }
  try {
    r->merge_group(std::move(result));
  } catch (const std::exception& e) {
    log::job(log::Level::error, id_, "merging result group {} of pass {} failed: {}", group, pass, e.what());
    stream_error_ = e.what();
  }
  std::lock_guard lock(mu_);
  merging_ = false;
}

void Job::hold_merges() {
  std::lock_guard gate(merge_gate_mu_);
  merges_held_ = true;
}

void Job::release_merges() {
  {
    std::lock_guard gate(merge_gate_mu_);
    merges_held_ = false;
  }
  merge_gate_cv_.notify_all();
}

bool Job::merges_held() {
  std::lock_guard gate(merge_gate_mu_);
  return merges_held_;
}

bool Job::mid_pass() const {
  std::lock_guard state_lock(state_mu_);
  std::lock_guard lock(mu_);
  return runner_ && runner_->groups_merged() > 0;
}

Job::PassCommit Job::commit_pass_locked(double checkpoint_interval_s) {
  PassCommit c;
  JobRunner& r = *runner_;
  version_++;
  c.version = version_;
  publishing_ = true;  // until this pass's progress event is in the log (publish_pass)
  c.cancel_now = cancel_requested_ && !r.finished();
  c.pause_now = preempt_requested_ && !c.cancel_now && !r.finished();
  if (!c.cancel_now && !c.pause_now && !r.finished()) c.next = plan_next(r);
  c.finished = c.cancel_now || r.finished() || (c.next.empty() && !c.pause_now);
  if (c.finished) c.next = PassWork{};
  const auto now = std::chrono::steady_clock::now();
  if (c.finished || now - last_checkpoint_ >= std::chrono::duration<double>(checkpoint_interval_s)) {
    last_checkpoint_ = now;
    c.checkpoint = true;
  }
  return c;
}

JobEnding Job::publish_pass(const std::vector<Block>& blocks, const PassCommit& c, FinishViews& views) {
  // The heavy views of the pass (progress event, status JSON, tile events, and for the
  // last pass the final result and facts: passes over every pixel of an image) are built
  // here without the lock, so status GETs and watchers never wait for them. The runner
  // is not mutated meanwhile: only the pass boundary changes it (the cancel below under
  // the lock), and the executors call cancelled/failed for a job only once its
  // pass_done has returned (the next pass starts after that).
  const JobRunner& r = *runner_;
  const JobDefinition* def = def_.get();
  PassViews pv = c.finished ? pass_events(def, r, blocks) : running_views(def, r, blocks);
  if (c.finished) {
    if (c.cancel_now) {
      std::lock_guard lock(mu_);
      runner_->cancel();  // takes effect at this boundary
    }
    views = finish_views(def, r, c.cancel_now ? progress_data(def, r) : pv.progress);
  }
  JobEnding ending;
  std::lock_guard lock(mu_);
  events_.append("progress", *pv.progress);
  for (TileEvent& t : pv.tiles) events_.append(std::move(t.type), std::move(t.data));
  watch_progress_ = std::move(pv.progress);
  watch_progress_version_ = c.version;
  publishing_ = false;
  engine_version_ = c.version;
  if (c.finished) {
    // Its ending is stored before it is published: until then the job reads as
    // running, with the last pass's figures.
    ending = ending_locked(unix_now(), std::nullopt, &views);
    finishing_ = true;
    engine_ = views.final_result;
    live_facts_ = views.facts;
  } else {
    engine_ = std::move(pv.engine);
    live_facts_ = std::move(pv.live);
  }
  return ending;
}

int Job::set_priority(int priority, bool put_back) {
  std::lock_guard lock(mu_);
  if (!put_back && is_terminal(status_)) {
    throw JobError(JobError::Kind::conflict, fmt::format("job {} has already finished ({}); its priority no longer "
                                                         "changes anything",
                                                         id_, job_status_name(status_)));
  }
  if (!put_back && finishing_) {
    throw JobError(JobError::Kind::conflict,
                   fmt::format("job {} has already finished; its result is being stored", id_));
  }
  version_++;  // its documents change, and the save that follows is newer than the last
  return priority_.exchange(priority);
}

}  // namespace tally
