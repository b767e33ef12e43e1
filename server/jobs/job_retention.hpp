#pragma once
// Job retention: which finished jobs to delete, oldest finished first, beyond the
// limits on age, count and stored bytes (--retain-max-age, --retain-max-jobs,
// --retain-max-bytes), and the thread that applies them every interval.
#include <cstdint>
#include <functional>
#include <memory>
#include <stop_token>
#include <string>
#include <thread>
#include <vector>

namespace tally {

class Job;

class JobRetention {
 public:
  struct Policy {
    double max_age_s = 0;    // 0: no limit
    size_t max_jobs = 0;     // 0: no limit
    uint64_t max_bytes = 0;  // 0: no limit
    double interval_s = 60;
    bool any() const { return max_age_s > 0 || max_jobs > 0 || max_bytes > 0; }
  };
  struct Finished {
    std::string id;
    double finished_at = 0;
    int64_t seq = 0;
    uint64_t bytes = 0;  // stored bytes (spec, result, checkpoint)
  };
  struct Retire {
    std::string id;
    std::string why;  // which limit, with the figures, for the log
  };

  explicit JobRetention(Policy policy) : policy_(policy) {}
  ~JobRetention() { stop(); }

  // The finished jobs to delete, oldest first (finish time, then submission order):
  // each beyond a limit counted over the jobs not deleted before it.
  std::vector<Retire> select(std::vector<Finished> done, double now) const;

  // Calls `apply` every interval on a thread of its own until stop() (if any limit is set).
  void start(std::function<void()> apply);
  void stop();

  const Policy& policy() const { return policy_; }

 private:
  const Policy policy_;
  std::jthread thread_;
};

// The finished jobs among `jobs` (each read under its own lock), for select().
std::vector<JobRetention::Finished> finished_jobs(const std::vector<std::shared_ptr<Job>>& jobs);

}  // namespace tally
