#include "server/jobs/cached_answers.hpp"

#include "common/engine/component_targets.hpp"
#include "common/engine/results_version.hpp"
#include "common/log/log.hpp"

namespace tally {

bool CachedAnswers::answers_its_spec(const JobDefinition* def, const RunFacts* f) {
  if (!def || !f || !ResultCache::reusable(f->stop_reason)) return false;
  // Computed by another generation of the engine (or one not recorded): its bits are not
  // the ones this build would compute for the same spec and seed.
  if (f->results_version != kResultsVersion) return false;
  const StopRule a = f->rule, b = def->stop_rule();
  return a.max_samples == b.max_samples && a.time_budget_s == b.time_budget_s && a.abs_error == b.abs_error &&
         a.rel_error == b.rel_error && a.confidence == b.confidence && a.min_samples == b.min_samples &&
         (a.component_targets == b.component_targets ||
          (a.component_targets && b.component_targets && *a.component_targets == *b.component_targets));
}

void CachedAnswers::offer(const Job& job, JobStatus status, const RunFacts* facts) {
  if (status == JobStatus::succeeded && answers_its_spec(job.def_.get(), facts)) {
    cache_.add(job.cache_key_, job.id(), job.owner(), facts->samples);
  }
}

std::optional<CachedAnswers::Answer> CachedAnswers::find(const std::string& key, const Submitter& who,
                                                         uint64_t max_samples, const SnapshotOf& snapshot_of) {
  const auto answer = [&]() -> std::optional<Answer> {
    const auto source = cache_.find(key, who.owner, who.reads_all, max_samples);
    if (!source) return std::nullopt;
    const std::optional<JobSnapshot> s = snapshot_of(*source);
    if (!s || s->status != JobStatus::succeeded || !s->final_result || !s->facts) return std::nullopt;
    std::optional<std::string> checkpoint;
    try {
      checkpoint = store_.load_checkpoint(*source);
    } catch (const std::exception& e) {
      log::job(log::Level::warn, *source, "reading its stored state to answer a submit from it failed: {}", e.what());
    }
    if (!checkpoint) return std::nullopt;
    return Answer{*source, s->final_result, s->facts, std::move(*checkpoint)};
  }();
  if (!answer) missed();
  return answer;
}

void CachedAnswers::answer(Job& job, const Answer& answer, const std::string& key,
                           std::shared_ptr<const JobDefinition> def, JobCaps caps) {
  job.cache_key_ = key;
  job.cached_from_ = answer.source;
  std::lock_guard jl(job.mu_);
  job.answer_locked(std::move(def), caps,
                    JobEnding{JobStatus::succeeded, "", job.created_at(), answer.final_result, answer.facts});
}

void CachedAnswers::answered(const std::string& key, const Job& job, uint64_t samples) {
  cache_.counted(true);
  cache_.add(key, job.id(), job.owner(), samples);
}

}  // namespace tally
