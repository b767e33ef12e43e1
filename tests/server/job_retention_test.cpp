// JobRetention::select (server/jobs/job_retention.hpp) on its own: oldest finished
// first, each limit counted over the jobs kept, and nothing selected without a limit.
#include "server/jobs/job_retention.hpp"

#include <gtest/gtest.h>

namespace tally::test {
namespace {

std::vector<std::string> ids(const std::vector<JobRetention::Retire>& r) {
  std::vector<std::string> out;
  for (const auto& x : r) out.push_back(x.id);
  return out;
}

// Finished at 100, 200, 200 (seq 3 before 4), 300; 10 bytes each but "d" 100.
std::vector<JobRetention::Finished> four() {
  return {{"d", 300, 5, 100}, {"c", 200, 4, 10}, {"b", 200, 3, 10}, {"a", 100, 1, 10}};
}

TEST(JobRetention, NoLimitSelectsNothing) {
  JobRetention r({});
  EXPECT_TRUE(r.select(four(), 1e9).empty());
}

TEST(JobRetention, MaxJobsKeepsTheNewest) {
  JobRetention r({.max_age_s = 0, .max_jobs = 2, .max_bytes = 0, .interval_s = 60});
  const auto out = r.select(four(), 400);
  EXPECT_EQ(ids(out), (std::vector<std::string>{"a", "b"}));
  EXPECT_EQ(out[0].why, "4 finished jobs (--retain-max-jobs 2)");
  EXPECT_EQ(out[1].why, "3 finished jobs (--retain-max-jobs 2)");
}

TEST(JobRetention, MaxAgeByFinishTime) {
  JobRetention r({.max_age_s = 150, .max_jobs = 0, .max_bytes = 0, .interval_s = 60});
  const auto out = r.select(four(), 400);  // a: 300 s, b and c: 200 s, d: 100 s
  EXPECT_EQ(ids(out), (std::vector<std::string>{"a", "b", "c"}));
  EXPECT_EQ(out[0].why, "finished 300 s ago (--retain-max-age 150 s)");
}

TEST(JobRetention, MaxBytesCountsWhatIsKept) {
  // 130 bytes in all; down to 110 takes two deletions (a, then b: 120, then 110).
  JobRetention r({.max_age_s = 0, .max_jobs = 0, .max_bytes = 110, .interval_s = 60});
  const auto out = r.select(four(), 400);
  EXPECT_EQ(ids(out), (std::vector<std::string>{"a", "b"}));
  EXPECT_EQ(out[1].why, "finished jobs take 120 bytes (--retain-max-bytes 110)");
}

}  // namespace
}  // namespace tally::test
