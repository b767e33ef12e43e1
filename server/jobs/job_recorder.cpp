#include "server/jobs/job_recorder.hpp"

#include <fmt/format.h>

#include "common/engine/checkpoint.hpp"
#include "common/log/log.hpp"
#include "common/protocol/job_json.hpp"
#include "common/protocol/job_kinds.hpp"
#include "common/spec/spec_reader.hpp"
#include "common/spec/stop_rule_json.hpp"

namespace tally {

using nlohmann::json;

namespace {
std::string dump(const json& j) { return j.dump(-1, ' ', false, json::error_handler_t::replace); }

// Thrown through the store by a checkpoint stream whose state changed under it.
struct CheckpointAbandoned : std::exception {
  const char* what() const noexcept override { return "checkpoint abandoned: the state changed while it was written"; }
};

// The results version of a stored job's state: its running state's, or a finished job's
// (its stored facts', `facts`; 0, unknown, for a job finished before facts were stored or
// whose facts are unreadable); nullopt for a job with no state (queued: it will compute
// with this build).
std::optional<uint32_t> stored_results_version(JobStatus status, const std::optional<json>& facts,
                                               const std::optional<JobState>& resumed) {
  if (resumed) return resumed->results_version;
  if (!is_terminal(status)) return std::nullopt;
  return facts && facts->is_object() ? facts->value("results_version", 0u) : 0u;
}

}  // namespace

JobRecorder::Pending JobRecorder::take(Job& job, bool with_checkpoint, const JobEnding* ending) const {
  Pending p;
  StoredJob& s = p.row;
  // A pass merges under state_mu_ alone (Job::merge_pass): a checkpoint's copy or pass
  // count is taken between merges.
  std::unique_lock between_merges(job.state_mu_, std::defer_lock);
  if (with_checkpoint) between_merges.lock();
  std::lock_guard lock(job.mu_);
  p.version = job.version_;
  s.id = job.id_;
  s.seq = job.seq_;
  s.spec = job.spec_text_;
  s.priority = job.priority();
  s.owner = job.owner_;
  const JobStatus status = ending ? ending->status : job.status_;
  const auto& final_result = ending ? ending->final_result : job.final_result_;
  const auto& facts = ending ? ending->facts : job.facts_;
  s.state = std::string(job_status_name(status));
  s.stop_rule = job.runner_  ? dump(stop_rule_to_json(job.runner_->rule()))
                : job.facts_ ? dump(stop_rule_to_json(job.facts_->rule))
                             : std::string("{}");
  s.error = ending ? ending->error : job.error_;
  if (is_terminal(status) && final_result && !final_result->is_null()) s.result = dump(*final_result);
  if (is_terminal(status) && facts) s.facts = dump(run_facts_json(*facts));
  if (with_checkpoint && job.runner_) {
    // Encoded later, without the lock. A small state is copied now (state_mu_ is held, so
    // it is the state at this boundary): its checkpoint always lands, however
    // slow the store. A big one (an image) is read from the live state, piece by piece,
    // when the store takes it: no copy of it.
    if (checkpoint_size_hint(job.runner_->state()) <= copy_bytes_.load()) {
      p.copy = std::make_shared<const JobState>(job.runner_->state());
    } else {
      p.runner = job.runner_;
      p.passes = job.runner_->state().passes;
    }
  }
  s.created_at = job.created_at_;
  s.started_at = job.started_at_;
  s.finished_at = ending ? ending->finished_at : job.finished_at_;
  return p;
}

bool JobRecorder::persist(Job& job, bool with_checkpoint, bool retry) {
  return store(job, take(job, with_checkpoint), retry);
}

bool JobRecorder::persist_with(Job& job, std::string checkpoint) {
  Pending p = take(job, false);
  p.row.checkpoint = std::move(checkpoint);
  return store(job, std::move(p), false);
}

bool JobRecorder::store(Job& job, Pending pending, bool retry) {
  StoredJob& s = pending.row;
  const uint64_t version = pending.version;
  // A small state's checkpoint is encoded from the copy take() made. A big one (an
  // image's is hundreds of MB, over a GB at 1080p) streams from the runner's state to
  // the store piece by piece: neither a copy of the state nor the whole encoding is
  // held. Each piece is encoded under the job's state_mu_; a
  // pass committed meanwhile (the state's passes moved on) abandons it: the store
  // keeps the checkpoint it had, and the next one is due at a later pass boundary.
  // After an abandoned one, the next checkpoint writes the state as it is when the store
  // takes it and keeps state_mu_ for the whole write: the job's next commit waits for
  // it, so a job whose checkpoint always takes longer than a pass still gets every
  // other one stored (a kill -9 loses a few intervals of its work, not all of it).
  uint64_t streamed = 0;
  if (pending.copy) {
    s.checkpoint_stream = [&](const CheckpointSink& sink) {
      streamed = write_checkpoint(*pending.copy, sink);
      return streamed;
    };
  } else if (pending.runner) {
    const bool hold = job.checkpoint_abandoned_.load();
    // `hold` by value: the stream runs inside store_.save, after this block has ended.
    s.checkpoint_stream = [&, hold](const CheckpointSink& sink) {
      if (hold) {  // after an abandoned one: the state as it is now, the commit waiting for the whole write
        std::lock_guard held(job.state_mu_);
        streamed = write_checkpoint(pending.runner->state(), sink);
        return streamed;
      }
      const auto steady = [&] {
        std::unique_lock held(job.state_mu_);
        if (pending.runner->state().passes != pending.passes) throw CheckpointAbandoned();
        return held;
      };
      std::unique_lock held = steady();
      streamed = write_checkpoint(pending.runner->state(), [&](std::string_view piece) {
        held.unlock();  // the store writes the piece (the writer's own bytes) without it
        sink(piece);
        held = steady();
      });
      return streamed;
    };
  }
  std::lock_guard save_lock(job.save_mu_);
  if (job.removed_ || version < job.saved_version_) return true;  // deleted meanwhile, or a newer state is stored
  try {
    store_.save(s);
  } catch (const CheckpointAbandoned&) {
    job.checkpoint_abandoned_ = true;
    log::job(log::Level::info, job.id_,
             "checkpoint of pass {} abandoned: the next pass was committed while it was written; the next one "
             "holds the commit until it is stored",
             pending.passes);
    return true;
  } catch (const std::exception& e) {
    // The job keeps running; the save is retried until stored, and until then the
    // server refuses new jobs and /readyz says why.
    health_.failed(e.what());
    log::job(log::Level::warn, job.id_, "saving the job failed{}: {}", retry ? " (retrying)" : "", e.what());
    if (retry) {
      std::lock_guard lock(retry_mu_);
      retry_[job.id_] = job.weak_from_this();
      retry_cv_.notify_all();
    }
    return false;
  }
  job.saved_version_ = version;
  if (pending.runner) job.checkpoint_abandoned_ = false;
  if (s.checkpoint) job.checkpoint_bytes_ = s.checkpoint->size();
  if (streamed > 0) job.checkpoint_bytes_ = streamed;
  job.stored_bytes_ = s.spec.size() + s.result.size() + s.facts.size() + job.checkpoint_bytes_;
  health_.succeeded();
  return true;
}

void JobRecorder::checkpoint_later(const std::shared_ptr<Job>& job) {
  {
    std::lock_guard lock(checkpoint_mu_);
    if (checkpoint_busy_.count(job->id_)) return;  // the previous one is still being written
    checkpoint_busy_.insert(job->id_);
  }
  Pending p = take(*job, true);
  // Streamed from the live state: a streamed pass's merges wait until it is stored
  // (for a job whose passes merge whole, only a commit abandons it, as store says).
  if (p.runner) job->hold_merges();
  std::lock_guard lock(checkpoint_mu_);
  checkpoints_.emplace_back(job, std::move(p));
  checkpoint_cv_.notify_all();
}

void JobRecorder::write_checkpoints(std::stop_token st) {
  // At the workers' priority, not below it: at nice 10 a 4K frame's checkpoint (0.8 GB)
  // got ~5% of a core beside two busy workers and landed only after the job's last pass
  // (bench/frame_4k_e2e.py: 38 s for what takes 6.5 s on an idle core), so a crash lost
  // the whole job. Now it takes its share for the few seconds it runs. A checkpoint due
  // while this one is still being written is skipped; the final save is synchronous.
  std::unique_lock lock(checkpoint_mu_);
  for (;;) {
    checkpoint_cv_.wait(lock, st, [&] { return !checkpoints_.empty(); });
    if (checkpoints_.empty()) return;  // stopped with nothing left (a stop drains the queue first)
    auto [job, pending] = std::move(checkpoints_.front());
    checkpoints_.erase(checkpoints_.begin());
    lock.unlock();
    const bool held = pending.runner != nullptr;
    store(*job, std::move(pending), true);
    if (held) job->release_merges();
    lock.lock();
    checkpoint_busy_.erase(job->id_);
  }
}

void JobRecorder::save_final_later(const std::shared_ptr<Job>& job, const JobEnding& ending,
                                   std::function<void(bool)> then) {
  Pending p = take(*job, true, &ending);
  {
    std::lock_guard lock(finals_mu_);
    if (finals_busy_ < kMaxQueuedFinals) {
      ++finals_busy_;
      finals_.push_back({job, std::move(p), std::move(then)});
      finals_cv_.notify_all();
      return;
    }
  }
  const bool stored = store(*job, std::move(p), false);
  then(stored);
}

void JobRecorder::flush_finals() {
  std::unique_lock lock(finals_mu_);
  finals_cv_.wait(lock, [&] { return finals_busy_ == 0; });
}

void JobRecorder::write_finals(std::stop_token st) {
  // At normal priority, unlike checkpoints: the job reads as finished, and its memory
  // is freed, only after this save.
  std::unique_lock lock(finals_mu_);
  for (;;) {
    finals_cv_.wait(lock, st, [&] { return !finals_.empty(); });
    if (finals_.empty()) return;  // stopped with nothing left (a stop drains the queue first)
    Final f = std::move(finals_.front());
    finals_.erase(finals_.begin());
    lock.unlock();
    const bool stored = store(*f.job, std::move(f.pending), false);
    f.then(stored);
    f = Final{};  // the state copy and the job let go before the count says done
    lock.lock();
    --finals_busy_;
    finals_cv_.notify_all();
  }
}

JobRecorder::JobRecorder(JobStore& store, JobCompiler compiler, JobLimits limits, size_t event_buffer)
    : store_(store), compiler_(std::move(compiler)), limits_(std::move(limits)), event_buffer_(event_buffer) {
  retrier_ = std::jthread([this](std::stop_token st) { retry_saves(st); });
  checkpointer_ = std::jthread([this](std::stop_token st) { write_checkpoints(st); });
  finisher_ = std::jthread([this](std::stop_token st) { write_finals(st); });
  loader_ = std::jthread([this](std::stop_token st) { run_loads(st); });
}

JobRecorder::~JobRecorder() {
  stop_loads();
  // Final saves and checkpoints still queued are written before the retrier stops (a
  // failed one is then left to the next start's recovery from the last stored checkpoint).
  finisher_.request_stop();
  if (finisher_.joinable()) finisher_.join();
  checkpointer_.request_stop();
  if (checkpointer_.joinable()) checkpointer_.join();
  retrier_.request_stop();
  if (retrier_.joinable()) retrier_.join();
}

void JobRecorder::probe_store() {
  const uint64_t failures = health_.failures();
  try {
    if (!store_.probe()) return;
  } catch (const std::exception& e) {
    // Still failing: /readyz keeps naming the last save's cause; at debug, once a second.
    if (log::enabled(log::Level::debug)) log::write(log::Level::debug, {}, fmt::format("store probe failed: {}", e.what()));
    return;
  }
  if (health_.failures() != failures) return;  // a save failed meanwhile: it says more than the probe
  health_.succeeded();
  log::info("the job store takes writes again (a probe write succeeded); ready for new jobs");
}

void JobRecorder::retry_saves(std::stop_token st) {
  std::unique_lock lock(retry_mu_);
  auto next_probe = std::chrono::steady_clock::now();
  while (!st.stop_requested()) {
    retry_cv_.wait_for(lock, st, std::chrono::milliseconds(200), [] { return false; });
    if (st.stop_requested()) continue;
    if (retry_.empty()) {
      // Nothing to retry (a failed submit is not kept), yet the store was failing: a probe
      // write, at most once a second, tells when it takes writes again.
      if (health_.problem() && std::chrono::steady_clock::now() >= next_probe) {
        next_probe = std::chrono::steady_clock::now() + kProbeInterval;
        lock.unlock();
        probe_store();
        lock.lock();
      }
      continue;
    }
    auto pending = std::move(retry_);
    retry_.clear();
    lock.unlock();
    for (auto& [id, weak] : pending) {
      const std::shared_ptr<Job> job = weak.lock();
      if (!job) continue;
      bool unfinished;
      {
        std::lock_guard jl(job->mu_);
        unfinished = !is_terminal(job->status_);
      }
      if (persist(*job, unfinished, false)) {
        log::job(log::Level::info, id, "saved after the store recovered");
      } else {
        std::lock_guard again(retry_mu_);
        retry_.emplace(id, weak);
      }
    }
    lock.lock();
  }
}

JobRecorder::Recovered JobRecorder::recover() {
  Recovered out;
  out.epoch = store_.next_epoch();
  std::vector<StoredJob> rows = store_.load_all();
  std::vector<std::shared_ptr<Job>> to_save;
  for (StoredJob& row : rows) {
    json spec;
    try {
      spec = json::parse(row.spec);
    } catch (const std::exception& e) {
      log::job(log::Level::warn, row.id, "stored spec is not JSON ({}); it is kept as text and cannot run",
               e.what());
      spec = row.spec;
    }
    const auto status = parse_job_status(row.state).value_or(JobStatus::failed);
    // A running job's state, read once here (its runner adopts it below).
    std::optional<JobState> resumed;
    std::optional<std::string> corrupt;
    if (!is_terminal(status) && row.checkpoint) {
      try {
        resumed = decode_checkpoint(*row.checkpoint);
      } catch (const CheckpointError& e) {
        corrupt = e.what();
      }
    }
    // A finished job's facts, parsed once: its results version (below) and its views.
    std::optional<json> facts;
    std::string facts_problem;
    if (is_terminal(status) && !row.facts.empty()) {
      try {
        facts = json::parse(row.facts);
      } catch (const std::exception& e) {
        facts_problem = e.what();
      }
    }
    // The spec as the engine that computed the job's state read it (a default changed
    // since is written in): the job shows and runs that spec.
    if (const std::optional<uint32_t> v = stored_results_version(status, facts, resumed)) spec = spec_as_of(spec, *v);
    auto job = std::make_shared<Job>(row.id, row.seq, spec, row.priority, row.created_at, out.epoch, event_buffer_,
                                     row.owner);
    job->caps_ = limits_.caps();
    job->stored_bytes_ = row.stored_bytes;
    job->status_ = status;
    job->error_ = row.error;
    job->started_at_ = row.started_at;
    job->finished_at_ = row.finished_at;
    if (!row.result.empty()) {
      try {
        job->final_result_ = std::make_shared<const json>(json::parse(row.result));
      } catch (const std::exception& e) {
        log::job(log::Level::warn, row.id,
                 "stored result is unreadable ({}); its status is rebuilt from the checkpoint", e.what());
      }
    }
    std::string problem;
    try {
      if (corrupt) throw CheckpointError(*corrupt);
      job->def_ = compiler_(spec, limits_);
      StopRule rule = job->def_->stop_rule();
      try {
        const json rj = json::parse(row.stop_rule);
        if (rj.is_object() && !rj.empty()) {
          SpecReader rd(rj, "/stop");
          rule = parse_stored_stop_rule(rd, limits_);
        }
      } catch (const std::exception& e) {
        log::job(log::Level::warn, row.id,
                 "stored stop rule is unreadable ({}); the spec's rule applies (an extend is lost)", e.what());
      }
      if (is_terminal(status)) {
        // A finished job's state stays on disk; the views read its stored facts.
        bool have_facts = false;
        if (facts) {
          try {
            job->facts_ = std::make_shared<const RunFacts>(parse_run_facts(*facts, rule));
            have_facts = true;
          } catch (const std::exception& e) {
            facts_problem = e.what();
          }
        }
        if (!facts_problem.empty()) {
          log::job(log::Level::warn, row.id, "stored facts are unreadable ({}); rebuilt from the checkpoint",
                   facts_problem);
        }
        if (!have_facts) {
          // Written before facts were stored: read the checkpoint once, keep the facts.
          if (const auto cp = store_.load_checkpoint(row.id)) {
            const JobRunner r(job->def_->kernel(), rule, limits_.caps(), decode_checkpoint(*cp));
            RunFacts f = run_facts(r);
            if (status == JobStatus::cancelled) f.stop_reason = StopReason::cancelled;
            job->facts_ = std::make_shared<const RunFacts>(std::move(f));
            to_save.push_back(job);
          }
        }
      } else if (resumed) {
        job->runner_ = std::make_unique<JobRunner>(job->def_->kernel(), rule, limits_.caps(), std::move(*resumed));
        job->build_idle_views_locked();  // here, not in the first status read (seconds at 4K)
      } else {
        // Queued and never started: its state is allocated when it starts.
        job->facts_ = std::make_shared<const RunFacts>(fresh_run_facts(rule));
      }
    } catch (const CheckpointError& e) {
      problem = fmt::format("the job's checkpoint is corrupt and it cannot resume: {}", e.what());
    } catch (const SpecError& e) {
      problem = fmt::format("the stored spec no longer compiles: {}", e.what());
    } catch (const std::exception& e) {
      problem = fmt::format("the job could not be restored: {}", e.what());
    }
    if (!problem.empty()) {
      job->runner_.reset();
      job->facts_.reset();
      if (!is_terminal(status)) {
        job->status_ = JobStatus::failed;
        job->error_ = problem;
        job->finished_at_ = unix_now();
        to_save.push_back(job);
      }
      log::job(log::Level::warn, job->id(), "{}", problem);
    }
    out.jobs.push_back(std::move(job));
  }
  for (auto& j : to_save) persist(*j, false);
  return out;
}

std::unique_ptr<JobRunner> JobRecorder::read_back(const Job& job, const JobDefinition& def,
                                                   const StopRule& rule) const {
  const std::optional<std::string> cp = store_.load_checkpoint(job.id());
  return cp ? std::make_unique<JobRunner>(def.kernel(), rule, job.caps_, decode_checkpoint(*cp))
            : std::make_unique<JobRunner>(def.kernel(), rule, job.caps_);
}

void JobRecorder::removed(Job& job) {
  std::lock_guard save_lock(job.save_mu_);
  job.removed_ = true;
  try {
    if (store_.remove(job.id())) {
      log::job(log::Level::debug, job.id(), "a save in flight had written the row back: deleted again");
    }
  } catch (const std::exception& e) {
    log::job(log::Level::warn, job.id(), "deleting the job's row again failed ({}): it may come back after a restart",
             e.what());
  }
}

void JobRecorder::load_later(std::function<void()> task) {
  {
    std::lock_guard lock(loads_mu_);
    if (!loads_stopped_) {
      loads_.push_back(std::move(task));
      loads_cv_.notify_all();
      return;
    }
  }
  task();
}

void JobRecorder::stop_loads() {
  {
    std::lock_guard lock(loads_mu_);
    loads_stopped_ = true;
  }
  loader_.request_stop();
  if (loader_.joinable()) loader_.join();
}

void JobRecorder::run_loads(std::stop_token st) {
  std::unique_lock lock(loads_mu_);
  for (;;) {
    loads_cv_.wait(lock, st, [&] { return !loads_.empty(); });
    if (loads_.empty()) return;  // stopped with nothing left (a stop drains the queue first)
    std::function<void()> task = std::move(loads_.front());
    loads_.erase(loads_.begin());
    lock.unlock();
    try {
      task();
    } catch (const std::exception& e) {
      log::error("reading a stored state back failed: {}", e.what());
    }
    lock.lock();
  }
}

}  // namespace tally
