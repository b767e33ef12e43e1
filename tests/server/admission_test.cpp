// Admission (server/jobs/admission.hpp) on its own: which job starts next, running and
// memory accounting, and the exact refusals every path that makes state shares.
#include "server/jobs/admission.hpp"

#include <gtest/gtest.h>

#include "fake_job.hpp"

namespace tally::test {
namespace {

std::shared_ptr<Job> job(const std::string& id, int64_t seq, int priority = 0, const std::string& owner = "") {
  return std::make_shared<Job>(id, seq, fake_spec(10), priority, 0.0, 1, 16, owner);
}

std::shared_ptr<Job> queued(Admission& a, const std::string& id, int64_t seq, int priority = 0,
                            const std::string& owner = "", uint64_t bytes = 0, uint64_t owner_max = UINT64_MAX) {
  auto j = job(id, seq, priority, owner);
  a.track(*j, bytes, owner_max);
  a.enqueue(j);
  return j;
}

std::string next_id(Admission& a) {
  auto j = a.next();
  return j ? j->id() : "";
}

TEST(Admission, HighestPriorityFirstThenSubmissionOrder) {
  Admission a({.max_running = 10, .max_queued = 10, .memory_budget = 0});
  queued(a, "a", 1, 0);
  queued(a, "b", 2, 3);
  queued(a, "c", 3, 3);
  queued(a, "d", 4, -2);
  EXPECT_EQ(next_id(a), "b");
  EXPECT_EQ(next_id(a), "c");
  EXPECT_EQ(next_id(a), "a");
  EXPECT_EQ(next_id(a), "d");
  EXPECT_EQ(next_id(a), "");
  EXPECT_EQ(a.queued(), 0u);
}

TEST(Admission, NoSlotNoStartAndOwnersAtTheirQuotaAreSkipped) {
  Admission a({.max_running = 2, .max_queued = 10, .memory_budget = 0});
  auto x1 = queued(a, "x1", 1, 5, "x", 0, 1);
  auto x2 = queued(a, "x2", 2, 5, "x", 0, 1);
  auto y1 = queued(a, "y1", 3, 0, "y", 0, 1);
  ASSERT_EQ(next_id(a), "x1");
  a.started(x1);
  // x is at its quota of 1: y1 goes before x2 despite the lower priority.
  ASSERT_EQ(next_id(a), "y1");
  a.started(y1);
  EXPECT_EQ(a.running(), 2u);
  EXPECT_EQ(next_id(a), "");  // no running slot
  a.stopped(*y1);
  EXPECT_EQ(next_id(a), "");  // a slot, but x is still at its quota
  a.stopped(*x1);
  EXPECT_EQ(next_id(a), "x2");
  EXPECT_EQ(a.running(), 0u);
}

TEST(Admission, FirstInLineWaitsForMemoryWhileJobsHoldingStatePass) {
  Admission a({.max_running = 10, .max_queued = 10, .memory_budget = 100});
  auto big = queued(a, "big", 1, 9, "", 80);
  ASSERT_EQ(next_id(a), "big");
  a.charge(*big);
  a.started(big);
  EXPECT_EQ(a.memory_used(), 80u);
  auto wide = queued(a, "wide", 2, 1, "", 30);
  auto small = queued(a, "small", 3, 0, "", 10);  // fits, but must not overtake "wide"
  auto held = queued(a, "held", 4, 0, "", 50);
  a.charge(*held);  // resumed: holds its state already
  EXPECT_EQ(a.memory_used(), 130u);
  EXPECT_EQ(next_id(a), "held");
  EXPECT_EQ(next_id(a), "");
  a.release(*big);
  a.release(*big);  // once only
  EXPECT_EQ(a.memory_used(), 50u);
  a.release(*held);
  EXPECT_EQ(a.memory_used(), 0u);
  EXPECT_EQ(next_id(a), "wide");  // nothing in memory: the first in line starts
  a.charge(*wide);
  EXPECT_EQ(next_id(a), "small");
  EXPECT_FALSE(a.charged(*small));
  EXPECT_TRUE(a.charged(*wide));
  a.forget(*wide);
  EXPECT_EQ(a.memory_used(), 0u);
}

TEST(Admission, OverBudgetNamesTheNeedAndTheBudget) {
  Admission none({.max_running = 1, .max_queued = 1, .memory_budget = 0});
  EXPECT_FALSE(none.over_budget(UINT64_MAX).has_value());
  Admission a({.max_running = 1, .max_queued = 1, .memory_budget = 64ULL << 20});
  EXPECT_FALSE(a.over_budget(64ULL << 20).has_value());
  EXPECT_EQ(a.over_budget(96ULL << 20).value_or(""),
            "the job needs 96.0 MiB of memory for its state and scene, more than the server's memory budget of 64.0 MiB "
            "(--memory-budget)");
}

TEST(Admission, RoomIsRefusedWithTheServersQueueOrTheOwnersQuota) {
  Admission a({.max_running = 1, .max_queued = 2, .memory_budget = 0});
  Submitter alice;
  alice.owner = "alice";
  alice.max_running = 1;
  alice.max_queued = 1;
  Submitter carol;
  carol.owner = "carol";
  EXPECT_NO_THROW(a.check_room(alice));
  auto r = queued(a, "r", 1, 0, "bob");
  ASSERT_EQ(next_id(a), "r");
  a.started(r);
  queued(a, "q1", 2, 0, "alice");
  try {
    a.check_room(alice);
    FAIL() << "alice has max_queued 1 and one job waiting";
  } catch (const JobError& e) {
    EXPECT_EQ(e.kind(), JobError::Kind::quota);
    EXPECT_STREQ(e.what(), "quota max_queued_jobs: \"alice\" already has 1 queued and 0 running jobs "
                           "(max_queued_jobs 1, max_running_jobs 1)");
  }
  EXPECT_NO_THROW(a.check_room(carol));
  queued(a, "q2", 3, 0, "carol");
  try {
    a.check_room(carol);
    FAIL() << "the server's queue holds 2 of 2";
  } catch (const JobError& e) {
    EXPECT_EQ(e.kind(), JobError::Kind::queue_full);
    EXPECT_STREQ(e.what(), "the job queue is full (2 queued, 1 running); retry later");
  }
}

}  // namespace
}  // namespace tally::test
