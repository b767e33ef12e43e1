#include "server/jobs/admission.hpp"

#include <fmt/format.h>

#include <algorithm>

#include "common/engine/job_state.hpp"

namespace tally {

namespace {

// The order jobs start in: highest priority first; among equal priorities the owner
// running fewer jobs (its fair share: a job paused for it does not start again before
// it), then submission order.
bool goes_before(const Job& a, const Job& b, const std::map<std::string, uint64_t>& running) {
  if (a.priority() != b.priority()) return a.priority() > b.priority();
  if (a.owner() != b.owner()) {
    const auto ra = running.find(a.owner()), rb = running.find(b.owner());
    const uint64_t na = ra == running.end() ? 0 : ra->second, nb = rb == running.end() ? 0 : rb->second;
    if (na != nb) return na < nb;
  }
  return a.seq() < b.seq();
}

}  // namespace

uint64_t Admission::state_bytes(const JobDefinition& def) {
  const Kernel& k = *def.kernel();
  return job_state_bytes(k.channel_count(), k.partition_count(), k.sum_count());
}

uint64_t Admission::memory_bytes(const JobDefinition& def) { return state_bytes(def) + def.kernel()->resident_bytes(); }

std::optional<std::string> Admission::over_budget(uint64_t need) const {
  if (limits_.memory_budget == 0 || need <= limits_.memory_budget) return std::nullopt;
  const auto mib = [](uint64_t b) { return fmt::format("{:.1f} MiB", static_cast<double>(b) / (1 << 20)); };
  return fmt::format("the job needs {} of memory for its state and scene, more than the server's memory budget of {} "
                     "(--memory-budget)",
                     mib(need), mib(limits_.memory_budget));
}

void Admission::check_room(const Submitter& who) const {
  if (queue_.size() >= limits_.max_queued && running_ >= limits_.max_running) {
    throw JobError(JobError::Kind::queue_full,
                   fmt::format("the job queue is full ({} queued, {} running); retry later", queue_.size(), running_));
  }
  if (who.max_queued == UINT64_MAX && who.max_running == UINT64_MAX) return;
  const uint64_t running = running_of(who.owner);
  const auto queued = static_cast<uint64_t>(
      std::count_if(queue_.begin(), queue_.end(), [&](const auto& j) { return j->owner() == who.owner; }));
  const bool would_wait = running >= who.max_running || running_ >= limits_.max_running;
  if (would_wait && queued >= who.max_queued) {
    throw JobError(JobError::Kind::quota,
                   fmt::format("quota max_queued_jobs: \"{}\" already has {} queued and {} running jobs "
                               "(max_queued_jobs {}, max_running_jobs {})",
                               who.owner, queued, running, who.max_queued, who.max_running));
  }
}

void Admission::track(const Job& job, uint64_t state_bytes, uint64_t owner_max_running) {
  Entry& e = entries_[job.id()];
  e.state_bytes = state_bytes;
  e.owner_max_running = owner_max_running;
}

void Admission::forget(const Job& job) {
  release(job);
  dequeue(job);
  entries_.erase(job.id());
}

void Admission::enqueue(std::shared_ptr<Job> job) { queue_.push_back(std::move(job)); }

bool Admission::dequeue(const Job& job) {
  const auto it = std::find_if(queue_.begin(), queue_.end(), [&](const auto& j) { return j.get() == &job; });
  if (it == queue_.end()) return false;
  queue_.erase(it);
  return true;
}

const Admission::Entry* Admission::entry(const Job& job) const {
  const auto it = entries_.find(job.id());
  return it == entries_.end() ? nullptr : &it->second;
}

uint64_t Admission::running_of(const std::string& owner) const {
  const auto r = running_by_owner_.find(owner);
  return r == running_by_owner_.end() ? 0 : r->second;
}

std::shared_ptr<Job> Admission::next() {
  if (running_ >= limits_.max_running) return nullptr;
  // Highest priority first, then the owner running fewer jobs, then submission order;
  // skipping owners at their running-jobs quota. The first in that order waits while
  // its state does not fit the memory budget (no smaller job overtakes it), except that
  // jobs already holding their state (resumed or extended) may start: they need nothing more.
  const auto before = [this](const std::shared_ptr<Job>& a, const std::shared_ptr<Job>& b) {
    return goes_before(*a, *b, running_by_owner_);
  };
  static const Entry none;
  const auto info = [&](const Job& j) -> const Entry& {
    const Entry* e = entry(j);
    return e ? *e : none;
  };
  std::shared_ptr<Job> best, best_charged;
  for (const auto& c : queue_) {
    if (running_of(c->owner()) >= info(*c).owner_max_running) continue;
    if (!best || before(c, best)) best = c;
    if (info(*c).charged && (!best_charged || before(c, best_charged))) best_charged = c;
  }
  if (!best) return nullptr;
  // With nothing in memory a job always starts (the budget may have shrunk since it
  // was admitted).
  const Entry& b = info(*best);
  std::shared_ptr<Job> pick = best;
  if (!(b.charged || limits_.memory_budget == 0 || memory_used_ == 0 ||
        memory_used_ + b.state_bytes <= limits_.memory_budget)) {
    pick = best_charged;
  }
  if (pick) dequeue(*pick);
  return pick;
}

void Admission::charge(const Job& job) {
  const auto it = entries_.find(job.id());
  if (it == entries_.end() || it->second.charged) return;
  it->second.charged = true;
  memory_used_ += it->second.state_bytes;
}

void Admission::release(const Job& job) {
  const auto it = entries_.find(job.id());
  if (it == entries_.end() || !it->second.charged) return;
  it->second.charged = false;
  memory_used_ -= it->second.state_bytes;
}

bool Admission::charged(const Job& job) const {
  const Entry* e = entry(job);
  return e && e->charged;
}

void Admission::started(const std::shared_ptr<Job>& job, double now) {
  ++running_;
  ++running_by_owner_[job->owner()];
  running_jobs_.push_back(Running{job, now, false});
}

void Admission::stopped(const Job& job) {
  std::erase_if(running_jobs_, [&](const Running& r) { return r.job.get() == &job; });
  if (running_ > 0) --running_;
  if (auto it = running_by_owner_.find(job.owner()); it != running_by_owner_.end() && --it->second == 0) {
    running_by_owner_.erase(it);
  }
}

std::shared_ptr<Job> Admission::preemption_victim(double now, double min_run_s) {
  if (running_ < limits_.max_running || queue_.empty() || running_jobs_.empty()) return nullptr;
  const auto before = [this](const std::shared_ptr<Job>& a, const std::shared_ptr<Job>& b) {
    return goes_before(*a, *b, running_by_owner_);
  };
  static const Entry none;
  std::shared_ptr<Job> waiting;
  for (const auto& c : queue_) {
    const Entry* e = entry(*c);
    if (running_of(c->owner()) >= (e ? *e : none).owner_max_running) continue;
    if (!waiting || before(c, waiting)) waiting = c;
  }
  if (!waiting) return nullptr;
  // Fair share: the running slots split over the owners with jobs running or waiting.
  std::map<std::string, bool> owners;
  for (const auto& r : running_jobs_) owners[r.job->owner()] = true;
  for (const auto& q : queue_) owners[q->owner()] = true;
  const double fair = static_cast<double>(limits_.max_running) / static_cast<double>(owners.size());
  const bool below_share = static_cast<double>(running_of(waiting->owner())) + 1 <= fair;
  Running* victim = nullptr;
  for (Running& r : running_jobs_) {
    if (r.chosen || now - r.since < min_run_s) continue;
    const Job& j = *r.job;
    const bool lower = j.priority() < waiting->priority();
    const bool over_share = below_share && j.owner() != waiting->owner() &&
                            static_cast<double>(running_of(j.owner())) > fair && j.priority() <= waiting->priority();
    if (!lower && !over_share) continue;
    if (!victim || j.priority() < victim->job->priority() ||
        (j.priority() == victim->job->priority() && j.seq() > victim->job->seq())) {
      victim = &r;
    }
  }
  if (!victim) return nullptr;
  // One victim per waiting job at a time: those chosen and not yet stopped already make room.
  size_t chosen = 0;
  for (const Running& r : running_jobs_) chosen += r.chosen ? 1 : 0;
  size_t waiting_count = 0;
  for (const auto& q : queue_) {
    const Entry* e = entry(*q);
    if (running_of(q->owner()) < (e ? *e : none).owner_max_running) ++waiting_count;
  }
  if (chosen >= waiting_count) return nullptr;
  victim->chosen = true;
  return victim->job;
}

}  // namespace tally
