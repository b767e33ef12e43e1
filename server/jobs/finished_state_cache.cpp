#include "server/jobs/finished_state_cache.hpp"

#include "common/engine/checkpoint.hpp"
#include "common/log/log.hpp"
#include "server/jobs/admission.hpp"

namespace tally {

std::shared_ptr<const JobState> FinishedStateCache::get(const JobSnapshot& s) {
  if (!is_terminal(s.status) || !s.def || !s.facts) return nullptr;
  {
    std::lock_guard lock(mu_);
    expire_locked();
    if (oversize_ && oversize_->id == s.id && oversize_->version == s.version) {
      oversize_used_ = std::chrono::steady_clock::now();
      return oversize_->state;
    }
    for (auto it = entries_.begin(); it != entries_.end(); ++it) {
      if (it->id == s.id && it->version == s.version) {
        entries_.splice(entries_.begin(), entries_, it);
        return entries_.front().state;
      }
    }
  }
  return load(s);
}

std::shared_ptr<const JobState> FinishedStateCache::load(const JobSnapshot& s) {
  std::optional<std::string> cp;
  std::shared_ptr<const JobState> st;
  try {
    cp = store_.load_checkpoint(s.id);
    if (!cp) return nullptr;
    JobState decoded = decode_checkpoint(*cp);
    s.def->kernel()->upgrade_state(decoded);  // an older layout (false if it is current or unknown)
    st = std::make_shared<const JobState>(std::move(decoded));
  } catch (const std::exception& e) {
    log::job(log::Level::warn, s.id, "reading the finished job's state from the store failed: {}", e.what());
    return nullptr;
  }
  const Kernel& k = *s.def->kernel();
  if (st->channels.size() != k.channel_count() || st->sums.size() != k.sum_count() ||
      st->partition_samples.size() != k.partition_count()) {
    log::job(log::Level::warn, s.id, "the stored state does not match the job ({} channels and {} sums, expected {} and {})",
             st->channels.size(), st->sums.size(), k.channel_count(), k.sum_count());
    return nullptr;
  }
  const uint64_t bytes = Admission::state_bytes(*s.def) / 2;  // one copy, not the runner's two
  std::lock_guard lock(mu_);
  ++loads_;
  erase_locked(s.id);  // an older version of the same job
  if (bytes <= capacity_) {
    entries_.push_front(Entry{s.id, s.version, st, bytes});
    bytes_ += bytes;
    while (bytes_ > capacity_) {
      bytes_ -= entries_.back().bytes;
      entries_.pop_back();
    }
  } else {
    oversize_ = Entry{s.id, s.version, st, bytes};  // replaces the one before
    oversize_used_ = std::chrono::steady_clock::now();
  }
  return st;
}

void FinishedStateCache::erase(const std::string& id) {
  std::lock_guard lock(mu_);
  erase_locked(id);
}

void FinishedStateCache::expire_locked() const {
  if (oversize_ && std::chrono::duration<double>(std::chrono::steady_clock::now() - oversize_used_).count() >=
                       oversize_idle_s_) {
    oversize_.reset();
  }
}

void FinishedStateCache::erase_locked(const std::string& id) {
  if (oversize_ && oversize_->id == id) oversize_.reset();
  for (auto it = entries_.begin(); it != entries_.end();) {
    if (it->id == id) {
      bytes_ -= it->bytes;
      it = entries_.erase(it);
    } else {
      ++it;
    }
  }
}

uint64_t FinishedStateCache::bytes() const {
  std::lock_guard lock(mu_);
  expire_locked();
  return bytes_ + (oversize_ ? oversize_->bytes : 0);
}

uint64_t FinishedStateCache::loads() const {
  std::lock_guard lock(mu_);
  return loads_;
}

}  // namespace tally
