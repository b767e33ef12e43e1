// FinishedStateCache (server/jobs/finished_state_cache.hpp) on its own: a finished job's
// state is read from the store once per version, served from memory after, evicted
// least recently used first beyond its capacity, and never served when it does not
// match the job.
#include "server/jobs/finished_state_cache.hpp"

#include <gtest/gtest.h>

#include <chrono>
#include <thread>

#include "common/engine/checkpoint.hpp"
#include "fake_job.hpp"
#include "server/jobs/admission.hpp"

namespace tally::test {
namespace {

// A store that counts checkpoint reads.
struct CountingStore : JobStore {
  std::unique_ptr<JobStore> inner = make_memory_store();
  int reads = 0;
  void save(const StoredJob& j) override { inner->save(j); }
  std::vector<StoredJob> load_all() override { return inner->load_all(); }
  std::optional<std::string> load_checkpoint(const std::string& id) override {
    ++reads;
    return inner->load_checkpoint(id);
  }
  bool remove(const std::string& id) override { return inner->remove(id); }
  uint64_t next_epoch() override { return inner->next_epoch(); }
};

struct Fixture {
  CountingStore store;
  std::shared_ptr<const JobDefinition> def = compile_fake_job(fake_spec(10, 0, 1, true), JobLimits{});

  // Stores a finished job whose channel i has mean `value + i`.
  JobSnapshot finished(const std::string& id, uint64_t version, double value, size_t channels = 0) {
    JobState st;
    st.channels.resize(channels ? channels : def->kernel()->channel_count());
    for (size_t i = 0; i < st.channels.size(); ++i) st.channels[i].add(value + static_cast<double>(i));
    st.partition_samples.assign(def->kernel()->partition_count(), 1);
    StoredJob row;
    row.id = id;
    row.state = "succeeded";
    row.checkpoint = encode_checkpoint(st);
    store.save(row);
    JobSnapshot s;
    s.id = id;
    s.version = version;
    s.status = JobStatus::succeeded;
    s.def = def;
    s.facts = std::make_shared<const RunFacts>();
    return s;
  }
  uint64_t one() const { return Admission::state_bytes(*def) / 2; }
};

TEST(FinishedStateCache, ReadsOncePerVersionThenServesFromMemory) {
  Fixture f;
  FinishedStateCache cache(f.store, 10 * f.one());
  const JobSnapshot a = f.finished("a", 3, 1.0);
  auto s1 = cache.get(a);
  ASSERT_TRUE(s1);
  EXPECT_EQ(s1->channels[5].mean, 6.0);
  auto s2 = cache.get(a);
  EXPECT_EQ(s1.get(), s2.get());
  EXPECT_EQ(f.store.reads, 1);
  EXPECT_EQ(cache.loads(), 1u);
  EXPECT_EQ(cache.bytes(), f.one());
  // A newer version (extended and finished again) is read again and replaces the old one.
  JobSnapshot a4 = f.finished("a", 4, 2.0);
  auto s3 = cache.get(a4);
  ASSERT_TRUE(s3);
  EXPECT_EQ(s3->channels[0].mean, 2.0);
  EXPECT_EQ(f.store.reads, 2);
  EXPECT_EQ(cache.bytes(), f.one());
  cache.erase("a");
  EXPECT_EQ(cache.bytes(), 0u);
}

TEST(FinishedStateCache, EvictsLeastRecentlyUsedBeyondCapacity) {
  Fixture f;
  FinishedStateCache cache(f.store, 2 * f.one());
  const JobSnapshot a = f.finished("a", 1, 1.0), b = f.finished("b", 1, 2.0), c = f.finished("c", 1, 3.0);
  cache.get(a);
  cache.get(b);
  cache.get(a);  // b is now the least recently used
  cache.get(c);  // evicts b
  EXPECT_EQ(f.store.reads, 3);
  EXPECT_EQ(cache.bytes(), 2 * f.one());
  cache.get(a);
  cache.get(c);
  EXPECT_EQ(f.store.reads, 3);
  cache.get(b);
  EXPECT_EQ(f.store.reads, 4);
  // A state larger than the whole cache is served, and not kept once idle.
  FinishedStateCache tiny(f.store, f.one() - 1, 0.0);
  EXPECT_TRUE(tiny.get(a));
  EXPECT_EQ(tiny.bytes(), 0u);
}

// A state over the whole capacity (a 4K frame's against 256 MiB) is kept alone while it
// is read: a run of tile reads decodes it once. Another oversize state replaces it; it
// goes once idle; the capacity still bounds the others.
TEST(FinishedStateCache, AStateOverTheCapacityIsKeptWhileItIsRead) {
  Fixture f;
  FinishedStateCache cache(f.store, f.one() - 1, 3600);
  const JobSnapshot a = f.finished("a", 1, 1.0), b = f.finished("b", 1, 2.0);
  const auto s1 = cache.get(a);
  ASSERT_TRUE(s1);
  for (int i = 0; i < 100; ++i) EXPECT_EQ(cache.get(a).get(), s1.get());
  EXPECT_EQ(f.store.reads, 1);
  EXPECT_EQ(cache.bytes(), f.one());
  const auto s2 = cache.get(b);  // replaces a
  ASSERT_TRUE(s2);
  EXPECT_EQ(s2->channels[0].mean, 2.0);
  EXPECT_EQ(cache.bytes(), f.one());
  EXPECT_EQ(cache.get(b).get(), s2.get());
  EXPECT_EQ(f.store.reads, 2);
  cache.get(a);
  EXPECT_EQ(f.store.reads, 3);
  cache.erase("a");  // deleted: its state goes at once
  EXPECT_EQ(cache.bytes(), 0u);

  FinishedStateCache idle(f.store, f.one() - 1, 0.05);
  ASSERT_TRUE(idle.get(a));
  std::this_thread::sleep_for(std::chrono::milliseconds(120));
  EXPECT_EQ(idle.bytes(), 0u) << "idle past oversize_idle_s";
  const int before = f.store.reads;
  ASSERT_TRUE(idle.get(a));
  EXPECT_EQ(f.store.reads, before + 1);
}

TEST(FinishedStateCache, UnfinishedMissingOrMismatchedStatesAreNotServed) {
  Fixture f;
  FinishedStateCache cache(f.store, 10 * f.one());
  JobSnapshot running = f.finished("r", 1, 1.0);
  running.status = JobStatus::running;
  EXPECT_FALSE(cache.get(running));
  JobSnapshot missing = running;
  missing.id = "nowhere";
  missing.status = JobStatus::succeeded;
  EXPECT_FALSE(cache.get(missing));
  const JobSnapshot wrong = f.finished("w", 1, 1.0, 3);  // 3 channels stored for a 64-channel job
  EXPECT_FALSE(cache.get(wrong));
  EXPECT_EQ(cache.bytes(), 0u);
}

}  // namespace
}  // namespace tally::test
