#include "server/jobs/job_retention.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <mutex>

#include "common/log/log.hpp"
#include "server/jobs/job.hpp"

namespace tally {

std::vector<JobRetention::Retire> JobRetention::select(std::vector<Finished> done, double now) const {
  const Policy& p = policy_;
  if (!p.any()) return {};
  std::sort(done.begin(), done.end(), [](const Finished& a, const Finished& b) {
    return a.finished_at != b.finished_at ? a.finished_at < b.finished_at : a.seq < b.seq;
  });
  size_t count = done.size();
  uint64_t bytes = 0;
  for (const Finished& f : done) bytes += f.bytes;
  std::vector<Retire> out;
  for (const Finished& f : done) {  // oldest first
    std::string why;
    if (p.max_age_s > 0 && now - f.finished_at > p.max_age_s) {
      why = fmt::format("finished {:.0f} s ago (--retain-max-age {} s)", now - f.finished_at, p.max_age_s);
    } else if (p.max_jobs > 0 && count > p.max_jobs) {
      why = fmt::format("{} finished jobs (--retain-max-jobs {})", count, p.max_jobs);
    } else if (p.max_bytes > 0 && bytes > p.max_bytes) {
      why = fmt::format("finished jobs take {} bytes (--retain-max-bytes {})", bytes, p.max_bytes);
    } else {
      break;  // every later job is newer, and the totals only shrink
    }
    --count;
    bytes -= f.bytes;
    out.push_back(Retire{f.id, std::move(why)});
  }
  return out;
}

void JobRetention::start(std::function<void()> apply) {
  if (!policy_.any() || thread_.joinable()) return;
  thread_ = std::jthread([this, apply = std::move(apply)](std::stop_token st) {
    std::mutex mu;
    std::condition_variable_any cv;
    std::unique_lock lock(mu);
    while (!st.stop_requested()) {
      cv.wait_for(lock, st, std::chrono::duration<double>(policy_.interval_s), [] { return false; });
      if (st.stop_requested()) break;
      try {
        apply();
      } catch (const std::exception& e) {
        log::warn("retention failed: {}", e.what());
      }
    }
  });
}

void JobRetention::stop() {
  thread_.request_stop();
  if (thread_.joinable()) thread_.join();
}

std::vector<JobRetention::Finished> finished_jobs(const std::vector<std::shared_ptr<Job>>& jobs) {
  std::vector<JobRetention::Finished> done;
  for (const auto& job : jobs) {
    std::lock_guard jl(job->mu_);
    if (is_terminal(job->status_)) done.push_back({job->id(), job->finished_at_, job->seq(), job->stored_bytes_});
  }
  return done;
}

}  // namespace tally
