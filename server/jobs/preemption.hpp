#pragma once
// Preemption and resume: running jobs asked to pause at their next pass boundary so that
// a waiting job can start (the victims Admission::preemption_victim picks), a paused job
// queued again, and a parked job (its state on disk: paused, or resumed at start beyond
// the memory budget) brought back when Admission starts it: it holds its running slot
// and its memory while its state is read back, then runs or is dropped.
//
// Thread-safety: none of its own, like Admission, which it drives: every call is made
// under the job manager's lock. It takes a job's own lock inside where stated (the
// manager's order: manager, then job). No threads inside: the manager stores a state and
// reads it back (on its recorder's threads) and calls in with the outcome.
#include <cstdint>
#include <memory>
#include <string>

#include "common/engine/job_runner.hpp"
#include "server/jobs/admission.hpp"
#include "server/jobs/job.hpp"

namespace tally {

class Preemption {
 public:
  // `min_run_s`: a job runs at least this long after it (re)started before it may be
  // paused; negative: never preempt.
  Preemption(Admission& admission, double min_run_s) : admission_(admission), min_run_s_(min_run_s) {}

  // Asks each running job Admission picks to pause at its next pass boundary (takes the
  // job's lock). `now`: steady clock seconds.
  void request_pauses(double now);
  // A job that paused at a pass boundary waits in the queue again, its running slot free
  // at once (the job that goes first starts beside the save of this one's state); its
  // state stays in memory, charged, until stored. Returns the job's version then, for
  // release_stored. Takes the job's lock.
  uint64_t requeue(const std::shared_ptr<Job>& job);
  // The paused job's state was stored at `version`: if it still waits unchanged since
  // (not resumed from memory meanwhile, not cancelled), the state leaves memory and its
  // memory charge is released (true: a waiting job may fit now). Takes the job's lock.
  bool release_stored(const std::shared_ptr<Job>& job, uint64_t version);

  // Admission chose a queued job to start; call under the job's lock. not_parked: start
  // it as usual; load: its state is on disk: it now holds its slot and memory, read the
  // state back, then call resumed(); loading: a read is under way already.
  enum class Start { not_parked, load, loading };
  Start start_locked(const std::shared_ptr<Job>& job, double now);
  // The state of a parked job read back (`runner`, or null and `error`). start: run it
  // now (Admission::next is skipped for it); dropped: cancelled meanwhile or shutting
  // down (its state stays on disk); failed: it failed (store it). Takes the job's lock.
  enum class Resumed { start, dropped, failed };
  Resumed resumed(const std::shared_ptr<Job>& job, std::unique_ptr<JobRunner> runner, const std::string& error,
                  double now, bool shutting_down);

  // A job read back from the store at a restart, known to Admission from now (its owner
  // held to `owner_max_running`); call under the job's lock. Unfinished: queued to resume
  // from its checkpoint (true), its state parked on disk if it does not fit the memory
  // budget beside those resumed before it.
  bool readmit_locked(const std::shared_ptr<Job>& job, uint64_t owner_max_running);

  uint64_t preemptions() const { return preemptions_; }  // pauses since start

 private:
  Admission& admission_;
  double min_run_s_;
  uint64_t preemptions_ = 0;
};

}  // namespace tally
