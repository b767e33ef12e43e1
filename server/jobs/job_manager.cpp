#include "server/jobs/job_manager.hpp"

#include "server/executor/in_process_executor.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <bit>
#include <chrono>
#include <cmath>
#include <ctime>
#include <random>
#include <set>

#include "common/engine/checkpoint.hpp"
#include "common/json/spec_reader.hpp"
#include "common/protocol/status_json.hpp"
#include "common/protocol/stop_rule_json.hpp"

namespace tally {

using nlohmann::json;

std::string_view job_status_name(JobStatus s) {
  switch (s) {
    case JobStatus::queued: return "queued";
    case JobStatus::running: return "running";
    case JobStatus::succeeded: return "succeeded";
    case JobStatus::failed: return "failed";
    case JobStatus::cancelled: return "cancelled";
  }
  return "unknown";
}

std::optional<JobStatus> parse_job_status(std::string_view s) {
  for (JobStatus x : {JobStatus::queued, JobStatus::running, JobStatus::succeeded, JobStatus::failed,
                      JobStatus::cancelled}) {
    if (job_status_name(x) == s) return x;
  }
  return std::nullopt;
}

double unix_now() {
  return std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
}

json time_json(double t) {
  if (t <= 0) return nullptr;
  const auto secs = static_cast<std::time_t>(std::floor(t));
  const int ms = std::min(999, static_cast<int>((t - std::floor(t)) * 1000.0));
  std::tm tm{};
  gmtime_r(&secs, &tm);
  return fmt::format("{:04}-{:02}-{:02}T{:02}:{:02}:{:02}.{:03}Z", tm.tm_year + 1900, tm.tm_mon + 1, tm.tm_mday,
                     tm.tm_hour, tm.tm_min, tm.tm_sec, ms);
}

json tally_bits_json(const JobState& state) {
  if (state.channels.empty()) return nullptr;
  const Tally& t = state.channels[0];
  return {{"n", t.n},
          {"mean", fmt::format("{:016x}", std::bit_cast<uint64_t>(t.mean))},
          {"m2", fmt::format("{:016x}", std::bit_cast<uint64_t>(t.m2))}};
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

JobStatus status_of(const JobRunner& r) {
  switch (r.stop_reason()) {
    case StopReason::none: return JobStatus::running;
    case StopReason::cancelled: return JobStatus::cancelled;
    case StopReason::failed: return JobStatus::failed;
    default: return JobStatus::succeeded;
  }
}

// Seconds until the job's rule fires, from the current throughput.
json eta_seconds(const JobRunner& r) {
  const double rate = r.samples_per_second();
  const JobState& s = r.state();
  double eta = std::numeric_limits<double>::infinity();
  if (r.finished()) return 0.0;
  if (auto p = r.prediction(); p && std::isfinite(p->seconds_remaining)) eta = p->seconds_remaining;
  const StopRule& rule = r.rule();
  if (rule.max_samples > 0 && rate > 0) {
    const double left = static_cast<double>(rule.max_samples > s.samples ? rule.max_samples - s.samples : 0);
    eta = std::min(eta, left / rate);
  }
  if (rule.time_budget_s > 0) eta = std::min(eta, std::max(0.0, rule.time_budget_s - s.compute_seconds));
  return std::isfinite(eta) ? json(eta) : json(nullptr);
}

json progress_event_json(const JobRunner& r) {
  json j = progress_json(r);
  j["pass"] = r.state().passes;
  j["eta_seconds"] = eta_seconds(r);
  return j;
}

}  // namespace

JobManager::JobManager(ManagerConfig config, JobStore& store, JobCompiler compiler)
    : config_(std::move(config)), store_(store), compiler_(std::move(compiler)) {
  ExecutorCallbacks cb;
  cb.pass_done = [this](const std::string& id, const PassWork& done, std::vector<BlockResult>&& results,
                        double wall) { return on_pass_done(id, done, std::move(results), wall); };
  cb.cancelled = [this](const std::string& id) { on_cancelled(id); };
  cb.failed = [this](const std::string& id, const std::string& error) { on_failed(id, error); };
  executor_ = config_.make_executor
                  ? config_.make_executor(std::move(cb))
                  : std::make_unique<InProcessExecutor>(config_.workers, std::move(cb), config_.chunk_target_s);
}

JobManager::~JobManager() { executor_->stop(); }

// ---------------------------------------------------------------- status JSON

json JobManager::engine_json_locked(const Job& job) const {
  if (is_terminal(job.status) && !job.final_result.is_null()) return job.final_result;
  if (!job.runner || !job.def) return json::object();
  json j = result_json(*job.runner, *job.def);
  j["summary"] = job.def->summary_line(*job.runner);
  j["eta_seconds"] = eta_seconds(*job.runner);
  j["bits"] = tally_bits_json(job.runner->state());
  return j;
}

json JobManager::status_json(Job& job, uint64_t* version) const {
  // What the executor says about the job (cluster mode: blocks pending / in flight,
  // or why it waits), asked before taking the job's lock.
  const std::optional<std::string> waiting = executor_->waiting_reason(job.id);
  std::optional<ExecutorStats::JobBlocks> blocks;
  if (const ExecutorStats es = executor_->stats(); es.blocks_by_job.count(job.id)) blocks = es.blocks_by_job.at(job.id);
  std::lock_guard lock(job.mu);
  if (version) *version = job.version;
  json j = engine_json_locked(job);
  j["id"] = job.id;
  j["state"] = std::string(job_status_name(job.status));
  j["priority"] = job.priority;
  j["spec"] = job.spec;
  j["plan"] = job.def ? job.def->plan() : json(nullptr);
  if (job.runner) j["stop_rule"] = stop_rule_to_json(job.runner->rule());
  if (!job.error.empty()) j["error_message"] = job.error;
  if (job.status == JobStatus::running && waiting) j["waiting_reason"] = *waiting;
  if (job.status == JobStatus::running && blocks) {
    j["blocks"] = {{"pending", blocks->pending}, {"in_flight", blocks->in_flight}, {"redelivered", blocks->redelivered}};
  }
  const double now = unix_now();
  const double end = job.finished_at > 0 ? job.finished_at : now;
  j["timing"] = {{"created_at", time_json(job.created_at)},
                 {"started_at", time_json(job.started_at)},
                 {"finished_at", time_json(job.finished_at)},
                 {"queued_seconds", (job.started_at > 0 ? job.started_at : now) - job.created_at},
                 {"wall_seconds", job.started_at > 0 ? end - job.started_at : 0.0},
                 {"compute_seconds", job.runner ? job.runner->state().compute_seconds : 0.0}};
  json links = {{"self", "/v1/jobs/" + job.id}, {"events", "/v1/jobs/" + job.id + "/events"}};
  if (job.def && job.def->image()) {
    links["image_exr"] = "/v1/jobs/" + job.id + "/image.exr";
    links["image_png"] = "/v1/jobs/" + job.id + "/image.png";
    links["tiles"] = "/v1/jobs/" + job.id + "/tiles/{n}";
  }
  j["links"] = links;
  return j;
}

std::string JobManager::status_body(Job& job) const {
  {
    std::lock_guard lock(job.mu);
    // The statistics change only at pass boundaries (version); the timing fields
    // of a running job also change with the clock, so its copy lives at most 1 s.
    if (job.cached_version == job.version && !job.cached_status.empty() &&
        (is_terminal(job.status) || std::chrono::steady_clock::now() - job.cached_at < std::chrono::seconds(1))) {
      return job.cached_status;
    }
  }
  uint64_t built_from = 0;
  std::string body = dump(status_json(job, &built_from));
  body.push_back('\n');
  std::lock_guard lock(job.mu);
  // Cache it only if the job did not change meanwhile (else the next GET rebuilds).
  if (built_from == job.version) {
    job.cached_status = body;
    job.cached_version = built_from;
    job.cached_at = std::chrono::steady_clock::now();
  }
  return body;
}

json JobManager::summary_json(Job& job) const {
  std::lock_guard lock(job.mu);
  json j;
  j["id"] = job.id;
  j["state"] = std::string(job_status_name(job.status));
  j["kind"] = job.spec.value("kind", "");
  j["priority"] = job.priority;
  j["created_at"] = time_json(job.created_at);
  if (job.runner) {
    const JobState& s = job.runner->state();
    j["samples"] = s.samples;
    j["passes"] = s.passes;
    if (!s.channels.empty() && s.channels[0].n > 0) {
      const Estimate e = job.runner->headline();  // an image job's mean radiance, else channel 0
      j["mean"] = std::isfinite(e.mean) ? json(e.mean) : json(nullptr);
      j["std_error"] = std::isfinite(e.std_error) ? json(e.std_error) : json(nullptr);
    }
    j["stop_reason"] = std::string(stop_reason_name(job.runner->stop_reason()));
  }
  if (!job.error.empty()) j["error_message"] = job.error;
  return j;
}

std::vector<Event> JobManager::snapshot_events(Job& job) const {
  std::lock_guard lock(job.mu);
  const uint64_t id = job.events.last_id();
  std::vector<Event> out;
  json st = {{"state", std::string(job_status_name(job.status))}};
  if (job.runner) st["stop_reason"] = std::string(stop_reason_name(job.runner->stop_reason()));
  if (!job.error.empty()) st["error_message"] = job.error;
  out.push_back(Event{id, "state", dump(st)});
  if (job.runner && job.runner->state().passes > 0) {
    out.push_back(Event{id, "progress", dump(progress_event_json(*job.runner))});
  }
  if (is_terminal(job.status)) {
    json end = st;
    if (job.runner) end["target_met"] = job.runner->target_met();
    out.push_back(Event{id, "end", dump(end)});
  }
  return out;
}

// ---------------------------------------------------------------- persistence

void JobManager::persist(Job& job, bool with_checkpoint) {
  StoredJob s;
  uint64_t version;
  {
    std::lock_guard lock(job.mu);
    version = job.version;
    s.id = job.id;
    s.seq = job.seq;
    s.spec = dump(job.spec);
    s.priority = job.priority;
    s.state = std::string(job_status_name(job.status));
    s.stop_rule = job.runner ? dump(stop_rule_to_json(job.runner->rule())) : std::string("{}");
    s.error = job.error;
    if (is_terminal(job.status) && !job.final_result.is_null()) s.result = dump(job.final_result);
    if (with_checkpoint && job.runner) s.checkpoint = encode_checkpoint(job.runner->state());
    s.created_at = job.created_at;
    s.started_at = job.started_at;
    s.finished_at = job.finished_at;
  }
  std::lock_guard save_lock(job.save_mu);
  if (version < job.saved_version) return;  // a newer state is already stored
  job.saved_version = version;
  try {
    store_.save(s);
  } catch (const std::exception& e) {
    // The job keeps running; the store's health shows on /readyz and in the log.
    fmt::print(stderr, "tally-server: saving job {} failed: {}\n", job.id, e.what());
  }
}

// ---------------------------------------------------------------- lifecycle

void JobManager::publish_state_locked(Job& job) {
  json st = {{"state", std::string(job_status_name(job.status))}};
  if (job.runner) st["stop_reason"] = std::string(stop_reason_name(job.runner->stop_reason()));
  if (!job.error.empty()) st["error_message"] = job.error;
  job.events.append("state", dump(st));
}

void JobManager::finish_locked(Job& job, double now) {
  job.status = job.runner ? status_of(*job.runner) : JobStatus::failed;
  if (job.status == JobStatus::running) job.status = JobStatus::succeeded;  // plan_pass had nothing left
  if (job.runner && job.runner->error_message() && job.error.empty()) job.error = *job.runner->error_message();
  job.finished_at = now;
  job.final_result = json();
  job.final_result = engine_json_locked(job);
  job.version++;
  publish_state_locked(job);
  json end = {{"state", std::string(job_status_name(job.status))}};
  if (job.runner) {
    end["stop_reason"] = std::string(stop_reason_name(job.runner->stop_reason()));
    end["target_met"] = job.runner->target_met();
  }
  if (!job.error.empty()) end["error_message"] = job.error;
  job.events.append("end", dump(end));
}

std::shared_ptr<Job> JobManager::submit(const json& spec, int priority) {
  std::shared_ptr<const JobDefinition> def = compiler_(spec, config_.limits);  // throws SpecError
  auto runner = std::make_unique<JobRunner>(def->kernel(), def->stop_rule(), config_.caps);
  std::shared_ptr<Job> job;
  {
    std::lock_guard lock(mu_);
    if (shutting_down_) throw JobError(JobError::Kind::unavailable, "the server is shutting down");
    if (queue_.size() >= config_.max_queued && running_ >= config_.max_running) {
      throw JobError(JobError::Kind::queue_full,
                     fmt::format("the job queue is full ({} queued, {} running); retry later", queue_.size(), running_));
    }
    job = std::make_shared<Job>(new_job_id(), next_seq_++, spec, clamp_priority(priority), unix_now(), epoch_,
                                config_.event_buffer);
    job->def = std::move(def);
    job->runner = std::move(runner);
    jobs_[job->id] = job;
    order_.push_back(job);
  }
  persist(*job, false);
  {
    std::lock_guard lock(mu_);
    queue_.push_back(job);
    start_queued_locked();
  }
  return job;
}

void JobManager::start_queued_locked() {
  while (running_ < config_.max_running && !queue_.empty() && !shutting_down_) {
    // Highest priority first, then submission order.
    auto it = std::min_element(queue_.begin(), queue_.end(), [](const auto& a, const auto& b) {
      return a->priority != b->priority ? a->priority > b->priority : a->seq < b->seq;
    });
    std::shared_ptr<Job> job = *it;
    queue_.erase(it);
    PassWork pass;
    ExecutorJob ej;
    {
      std::lock_guard jl(job->mu);
      if (job->status != JobStatus::queued || !job->runner) continue;
      job->status = JobStatus::running;
      if (job->started_at <= 0) job->started_at = unix_now();
      job->version++;
      publish_state_locked(*job);
      pass.pass = job->runner->state().passes;
      pass.blocks = job->runner->plan_pass();
      pass.pass_input = job->runner->pass_input();
      if (pass.empty()) {
        finish_locked(*job, unix_now());
      } else {
        ej.id = job->id;
        ej.kernel = job->def->kernel();
        ej.spec_json = job->spec.dump();
        ej.epoch = epoch_;
        ej.priority = job->priority;
      }
    }
    if (pass.empty()) {
      // Nothing to run (restored already complete): store the final state.
      persist(*job, true);
      continue;
    }
    ++running_;
    executor_->add(std::move(ej), std::move(pass));
  }
}

void JobManager::job_left_scheduler() {
  std::lock_guard lock(mu_);
  if (running_ > 0) --running_;
  start_queued_locked();
}

PassWork JobManager::on_pass_done(const std::string& id, const PassWork& done, std::vector<BlockResult>&& results,
                                  double wall) {
  const std::shared_ptr<Job> job = find(id);
  if (!job) return {};
  const std::vector<Block>& blocks = done.blocks;
  PassWork next;
  bool finished = false, checkpoint = false;
  {
    std::lock_guard lock(job->mu);
    JobRunner& r = *job->runner;
    try {
      r.commit_pass(std::move(results), wall);
    } catch (const std::exception& e) {
      r.fail(fmt::format("internal error committing a pass: {}", e.what()));
    }
    job->version++;
    job->events.append("progress", dump(progress_event_json(r)));
    if (const ImageSource* img = job->def->image()) {
      std::set<uint32_t> tiles;
      for (const Block& b : blocks) tiles.insert(img->tile_of_partition(b.partition));
      for (uint32_t t : tiles) {
        const TileRect rc = img->tile_rect(t);
        job->events.append("tile", dump(json{{"tile", t}, {"x", rc.x}, {"y", rc.y}, {"w", rc.w}, {"h", rc.h},
                                             {"pass", r.state().passes}}));
      }
    }
    if (job->cancel_requested && !r.finished()) r.cancel();  // takes effect at this boundary
    if (!r.finished()) {
      next.pass = r.state().passes;
      next.blocks = r.plan_pass();
      next.pass_input = r.pass_input();
    }
    if (r.finished() || next.empty()) {
      finish_locked(*job, unix_now());
      finished = true;
      next = PassWork{};
    }
    const auto now = std::chrono::steady_clock::now();
    if (finished || now - job->last_checkpoint >= std::chrono::duration<double>(config_.checkpoint_interval_s)) {
      job->last_checkpoint = now;
      checkpoint = true;
    }
  }
  if (checkpoint) persist(*job, true);
  if (finished) job_left_scheduler();
  return next;
}

void JobManager::on_failed(const std::string& id, const std::string& error) {
  const std::shared_ptr<Job> job = find(id);
  if (!job) return;
  {
    std::lock_guard lock(job->mu);
    if (is_terminal(job->status)) return;
    // The partial pass was dropped; the runner is at its last pass boundary.
    job->runner->fail(error);
    finish_locked(*job, unix_now());
  }
  persist(*job, true);
  job_left_scheduler();
}

void JobManager::on_cancelled(const std::string& id) {
  const std::shared_ptr<Job> job = find(id);
  if (!job) return;
  {
    std::lock_guard lock(job->mu);
    if (is_terminal(job->status)) return;
    // The partial pass was dropped; the runner is at its last pass boundary.
    job->runner->cancel();
    finish_locked(*job, unix_now());
  }
  persist(*job, true);
  job_left_scheduler();
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
    std::lock_guard jl(job->mu);
    if (is_terminal(job->status)) {
      throw JobError(JobError::Kind::conflict,
                     fmt::format("job {} has already finished ({})", id, job_status_name(job->status)));
    }
    if (job->status == JobStatus::queued) {
      queue_.erase(std::remove(queue_.begin(), queue_.end(), job), queue_.end());
      if (job->runner) job->runner->cancel();
      finish_locked(*job, unix_now());
      job->status = JobStatus::cancelled;
      was_queued = true;
    } else {
      job->cancel_requested = true;
    }
  }
  if (was_queued) {
    persist(*job, false);
    return job;
  }
  executor_->cancel(id);  // may run on_cancelled right here
  return job;
}

std::shared_ptr<Job> JobManager::extend(const std::string& id, const StopRule& rule) {
  std::shared_ptr<Job> job = find(id);
  if (!job) throw JobError(JobError::Kind::not_found, fmt::format("no job with id \"{}\"", id));
  {
    std::lock_guard lock(mu_);
    if (shutting_down_) throw JobError(JobError::Kind::unavailable, "the server is shutting down");
    std::lock_guard jl(job->mu);
    if (!is_terminal(job->status)) {
      throw JobError(JobError::Kind::conflict,
                     fmt::format("job {} is still {}; extend a finished job", id, job_status_name(job->status)));
    }
    if (job->status == JobStatus::failed || !job->runner || !job->def) {
      throw JobError(JobError::Kind::conflict,
                     fmt::format("job {} failed{}; a failed job cannot be extended", id,
                                 job->error.empty() ? "" : ": " + job->error));
    }
    JobRunner trial = *job->runner;  // leave the job untouched if the rule is refused
    trial.extend(rule);
    if (trial.finished()) {
      throw JobError(JobError::Kind::conflict,
                     fmt::format("the new rule is already met by job {} ({}); ask for more", id,
                                 stop_reason_name(trial.stop_reason())));
    }
    *job->runner = std::move(trial);
    job->status = JobStatus::queued;
    job->cancel_requested = false;
    job->error.clear();
    job->finished_at = 0;
    job->final_result = json();
    job->version++;
    publish_state_locked(*job);
  }
  persist(*job, false);
  std::lock_guard lock(mu_);
  queue_.push_back(job);
  start_queued_locked();
  return job;
}

// ---------------------------------------------------------------- recovery, shutdown

void JobManager::recover() {
  epoch_ = store_.next_epoch();
  std::vector<StoredJob> rows = store_.load_all();
  std::vector<std::shared_ptr<Job>> to_save;
  for (StoredJob& row : rows) {
    json spec;
    try {
      spec = json::parse(row.spec);
    } catch (const std::exception&) {
      spec = row.spec;
    }
    auto job = std::make_shared<Job>(row.id, row.seq, spec, row.priority, row.created_at, epoch_, config_.event_buffer);
    const auto status = parse_job_status(row.state).value_or(JobStatus::failed);
    job->status = status;
    job->error = row.error;
    job->started_at = row.started_at;
    job->finished_at = row.finished_at;
    if (!row.result.empty()) {
      try {
        job->final_result = json::parse(row.result);
      } catch (const std::exception&) {
      }
    }
    std::string problem;
    try {
      job->def = compiler_(spec, config_.limits);
      StopRule rule = job->def->stop_rule();
      try {
        const json rj = json::parse(row.stop_rule);
        if (rj.is_object() && !rj.empty()) {
          SpecReader rd(rj, "/stop");
          rule = parse_stop_rule(rd, config_.limits);
        }
      } catch (const std::exception&) {
      }
      if (row.checkpoint) {
        JobState st = decode_checkpoint(*row.checkpoint);
        job->runner = std::make_unique<JobRunner>(job->def->kernel(), rule, config_.caps, std::move(st));
      } else {
        job->runner = std::make_unique<JobRunner>(job->def->kernel(), rule, config_.caps);
      }
    } catch (const CheckpointError& e) {
      problem = fmt::format("the job's checkpoint is corrupt and it cannot resume: {}", e.what());
    } catch (const SpecError& e) {
      problem = fmt::format("the stored spec no longer compiles: {}", e.what());
    } catch (const std::exception& e) {
      problem = fmt::format("the job could not be restored: {}", e.what());
    }
    if (!problem.empty()) {
      job->runner.reset();
      if (!is_terminal(status)) {
        job->status = JobStatus::failed;
        job->error = problem;
        job->finished_at = unix_now();
        to_save.push_back(job);
      }
      fmt::print(stderr, "tally-server: job {}: {}\n", job->id, problem);
    }
    std::lock_guard lock(mu_);
    jobs_[job->id] = job;
    order_.push_back(job);
    next_seq_ = std::max(next_seq_, row.seq + 1);
    if (!is_terminal(job->status)) {
      job->status = JobStatus::queued;
      queue_.push_back(job);
    }
  }
  for (auto& j : to_save) persist(*j, false);
  std::lock_guard lock(mu_);
  start_queued_locked();
}

void JobManager::shutdown() {
  {
    std::lock_guard lock(mu_);
    if (shutting_down_) return;
    shutting_down_ = true;
  }
  executor_->stop();  // chunks in flight finish; partial passes are dropped
  for (const auto& job : list()) {
    bool unfinished;
    {
      std::lock_guard jl(job->mu);
      unfinished = !is_terminal(job->status);
    }
    if (unfinished) persist(*job, true);  // the state at its last pass boundary
    job->events.append("shutdown",
                       dump(json{{"reason", "the server is shutting down"},
                                 {"resumes", unfinished}}));
    job->events.close();
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
    std::lock_guard jl(j->mu);
    s.jobs_by_state[std::string(job_status_name(j->status))]++;
    if (j->status == JobStatus::running && j->runner) s.samples_per_second += j->runner->samples_per_second();
  }
  const ExecutorStats es = executor_->stats();
  s.samples_total = es.samples_done;
  s.workers = es.workers;
  s.busy_workers = es.busy_workers;
  return s;
}

}  // namespace tally
