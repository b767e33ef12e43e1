// Issue 27 N7: the memory budget holds for every path that makes state. An extended
// job and a job resumed at start beyond the budget wait with their state on disk and
// are read back when they start; before, extend and recovery charged every state at
// once (8 extended 384² jobs: 1.36 GB charged against a 512 MB budget).
#include <gtest/gtest.h>

#include "server_test_support.hpp"

namespace tally::test {
namespace {

using nlohmann::json;

// A fake image job's state (64 channels, 4 partitions), twice (Admission::state_bytes).
constexpr uint64_t kOne = 2 * (64 * sizeof(Tally) + 4 * sizeof(uint64_t));

JobStatus status_of(JobManager& m, const std::string& id) { return m.snapshot(id).status; }

TEST(AdmissionMemory, ExtendedJobsWaitOnDiskUntilTheirStateFits) {
  ManagerConfig mc = test_manager_config(1);
  mc.max_running = 4;
  mc.memory_budget = kOne + kOne / 2;
  auto store = make_memory_store();
  JobManager m(mc, *store, compile_fake_job);
  m.recover();
  std::vector<std::string> ids;
  for (uint64_t seed = 1; seed <= 3; ++seed) {
    ids.push_back(m.submit(fake_spec(400, 0, seed, true))->id());
    ASSERT_TRUE(wait_until([&] { return status_of(m, ids.back()) == JobStatus::succeeded; }));
  }
  ASSERT_TRUE(wait_until([&] { return m.stats().memory_used == 0; }));
  StopRule more;
  more.max_samples = kForever;
  for (const auto& id : ids) m.extend(id, more);
  ASSERT_TRUE(wait_until([&] { return status_of(m, ids[0]) == JobStatus::running; }));
  std::this_thread::sleep_for(std::chrono::milliseconds(200));
  EXPECT_EQ(m.stats().memory_used, kOne) << "one extended state in memory; the others wait on disk";
  EXPECT_EQ(status_of(m, ids[1]), JobStatus::queued);
  EXPECT_EQ(status_of(m, ids[2]), JobStatus::queued);
  // The first stops: the next is read back and goes on from its 400 samples.
  m.cancel(ids[0]);
  ASSERT_TRUE(wait_until([&] { return status_of(m, ids[1]) == JobStatus::running; }));
  EXPECT_LE(m.stats().memory_used, mc.memory_budget);
  const JobSnapshot s = m.snapshot(ids[1], JobManager::SnapshotOf::state);
  ASSERT_TRUE(s.runner);
  EXPECT_GE(s.runner->state().samples, 400u);
  EXPECT_EQ(status_of(m, ids[2]), JobStatus::queued);
  m.cancel(ids[1]);
  m.cancel(ids[2]);
  m.shutdown();
}

TEST(AdmissionMemory, JobsResumedBeyondTheBudgetWaitOnDisk) {
  auto store = make_memory_store();
  std::vector<std::string> ids;
  std::vector<uint64_t> saved;
  {
    ManagerConfig mc = test_manager_config(1);
    mc.max_running = 4;
    JobManager m(mc, *store, compile_fake_job);
    m.recover();
    for (uint64_t seed = 1; seed <= 3; ++seed) ids.push_back(m.submit(fake_spec(kForever, 1, seed, true))->id());
    for (const auto& id : ids) {
      ASSERT_TRUE(wait_until([&] {
        const JobSnapshot s = m.snapshot(id, JobManager::SnapshotOf::state);
        return s.runner && s.runner->state().passes >= 2;
      }));
    }
    m.shutdown();  // each checkpointed at its last pass boundary
  }
  ManagerConfig mc = test_manager_config(1);
  mc.max_running = 4;
  mc.memory_budget = kOne + kOne / 2;
  JobManager m(mc, *store, compile_fake_job);
  m.recover();
  EXPECT_EQ(m.stats().memory_used, kOne) << "one resumed state in memory; the others wait on disk";
  ASSERT_TRUE(wait_until([&] { return status_of(m, ids[0]) == JobStatus::running; }));
  EXPECT_EQ(status_of(m, ids[1]), JobStatus::queued);
  EXPECT_EQ(status_of(m, ids[2]), JobStatus::queued);
  const uint64_t before = m.snapshot(ids[1]).facts->samples;
  EXPECT_GT(before, 0u) << "the waiting job shows the figures of its checkpoint";
  m.cancel(ids[0]);
  ASSERT_TRUE(wait_until([&] { return status_of(m, ids[1]) == JobStatus::running; }));
  const JobSnapshot s = m.snapshot(ids[1], JobManager::SnapshotOf::state);
  ASSERT_TRUE(s.runner);
  EXPECT_GE(s.runner->state().samples, before);
  EXPECT_LE(m.stats().memory_used, mc.memory_budget);
  m.cancel(ids[1]);
  m.cancel(ids[2]);
  m.shutdown();
}

}  // namespace
}  // namespace tally::test
