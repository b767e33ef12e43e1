// Issue 32, preemption: with every running slot taken, a waiting job of higher priority
// (or of an owner below its fair share) pauses the lowest-priority running job at its
// next pass boundary. The paused job's state is stored and released, it reads as
// queued with waiting_reason "preempted", and it resumes later to the same bits as a
// run nobody paused (integration, image and VEGAS jobs). A job that started or resumed
// less than the minimum run time ago is not paused (no thrash).
#include <gtest/gtest.h>

#include "common/protocol/job_kinds.hpp"
#include "common/protocol/job_json.hpp"
#include "gated_store.hpp"
#include "server_test_support.hpp"

namespace tally::test {
namespace {

using nlohmann::json;

ManagerConfig one_slot(double min_run_s) {
  ManagerConfig mc = test_manager_config(1);
  mc.max_running = 1;
  mc.preempt_min_run_s = min_run_s;
  return mc;
}

JobStatus status_of(JobManager& m, const std::string& id) { return m.snapshot(id).status; }
uint64_t passes_of(JobManager& m, const std::string& id) {
  const JobSnapshot s = m.snapshot(id, JobManager::SnapshotOf::state);
  return s.runner ? s.runner->state().passes : s.facts ? s.facts->passes : 0;
}
bool has_event(JobManager& m, const std::string& id, const std::string& type) {
  const EventLog& log = m.find(id)->events();
  for (const Event& e : log.read_after(log.first_id() - 1, 100000).events) {
    if (e.type == type) return true;
  }
  return false;
}

// Runs `spec` unpaused, then again while a priority-5 job takes its slot after its first
// pass; both end with the same bits.
void expect_preempted_run_is_bit_identical(const json& spec) {
  auto store = make_memory_store();
  JobManager m(one_slot(0), *store, compile_any);
  m.recover();
  const std::string ref = m.submit(spec, 0)->id();
  ASSERT_TRUE(wait_until([&] { return status_of(m, ref) == JobStatus::succeeded; }, 120));
  const json want = m.snapshot(ref).final_result->at("bits");

  const std::string low = m.submit(spec, 0, {}, /*use_cache=*/false)->id();
  ASSERT_TRUE(wait_until([&] { return passes_of(m, low) >= 1; }, 60));
  const std::string high = m.submit(fake_spec(kForever, 1, 99), 5)->id();
  ASSERT_TRUE(wait_until([&] { return status_of(m, high) == JobStatus::running; }, 60))
      << "the priority-5 job starts once the running one pauses";
  {
    const JobSnapshot s = m.snapshot(low);
    ASSERT_EQ(s.status, JobStatus::queued) << "it finished before its next pass boundary: make it longer";
    EXPECT_EQ(s.executor.waiting_reason, "preempted");
    EXPECT_TRUE(wait_until([&] { return !m.snapshot(low, JobManager::SnapshotOf::state).runner; }, 30))
        << "its state is stored, then leaves memory";
    EXPECT_TRUE(has_event(m, low, "preempted"));
    const json summary = summary_json(s);
    EXPECT_EQ(summary.at("waiting_reason"), "preempted");
  }
  EXPECT_EQ(m.stats().preemptions, 1u);
  m.cancel(high);
  ASSERT_TRUE(wait_until([&] { return status_of(m, low) == JobStatus::succeeded; }, 120));
  EXPECT_EQ(m.snapshot(low).final_result->at("bits"), want) << spec.dump();
  EXPECT_EQ(m.snapshot(low).final_result->at("result"), m.snapshot(ref).final_result->at("result"));
  m.shutdown();
}

TEST(Preemption, IntegrationJobResumesBitIdentical) {
  expect_preempted_run_is_bit_identical(json{{"kind", "integrate"},
                                             {"seed", 3},
                                             {"integrand", {{"expression", "exp(-x*x-y*y)"}}},
                                             {"domain", {{"type", "box"}, {"lower", {0, 0}}, {"upper", {1, 1}}}},
                                             {"stop", {{"max_samples", 20000000}}}});
}

TEST(Preemption, VegasJobResumesBitIdentical) {
  const json genz = {{"builtin", "genz"}, {"family", "discontinuous"}, {"a", {3.0, 5.0, 2.0}}, {"u", {0.6, 0.45, 0.5}}};
  expect_preempted_run_is_bit_identical(json{{"kind", "integrate"},
                                             {"seed", 5},
                                             {"integrand", genz},
                                             {"estimator", {{"type", "vegas"}}},
                                             {"stop", {{"max_samples", 4096 * 400}}}});
}

TEST(Preemption, ImageJobResumesBitIdentical) {
  json spec = json::parse(R"({
    "kind": "lighting", "seed": 7,
    "scene": {
      "camera": {"position": [0, -4.5, 3.2], "look_at": [0, 0, 0.6], "up": [0, 0, 1], "fov_deg": 50,
                 "resolution": [48, 32]},
      "materials": {"white": {"type": "diffuse", "albedo": [0.8, 0.8, 0.8]},
                    "lamp": {"type": "emissive", "radiance": [5, 5, 5], "two_sided": false}},
      "shapes": [
        {"type": "quad", "corner": [-3, -3, 0], "edge_u": [6, 0, 0], "edge_v": [0, 6, 0], "material": "white"},
        {"type": "quad", "corner": [-0.5, -0.5, 2], "edge_u": [0, 1, 0], "edge_v": [1, 0, 0], "material": "lamp"}]
    },
    "query": {"type": "image", "max_pass_spp": 4}, "estimators": ["mis"], "stop": {"max_samples": 96}
  })");
  expect_preempted_run_is_bit_identical(spec);
}

// The job that goes first starts at the paused job's pass boundary, not once the paused
// job's state is written (an image's takes hundreds of ms; the pause used to store it on
// the thread that published the pass, and only then free the slot). Here the paused
// job's save is held at a gate: the urgent job runs meanwhile, the paused job keeps its
// state in memory until the save lands, then releases it, and still ends bit-identical.
TEST(Preemption, TheUrgentJobStartsBeforeThePausedJobsStateIsStored) {
  // Once armed (just before the urgent submit), every save of a state waits at the gate:
  // the pause's, and any periodic checkpoint of the low job (the pause's save then waits
  // behind it for the job's save lock).
  auto armed = std::make_shared<std::atomic<bool>>(false);
  auto owned = std::make_unique<GatedStore>(make_memory_store(), [armed](const StoredJob& j) {
    return *armed && (j.checkpoint.has_value() || static_cast<bool>(j.checkpoint_stream));
  });
  GatedStore* store = owned.get();
  struct OpenAtExit {  // a failed assertion must not leave the loader held at the gate
    GatedStore* s;
    ~OpenAtExit() { s->open(); }
  } open_at_exit{store};
  JobManager m(one_slot(0), *store, compile_any);
  m.recover();
  const json spec = {{"kind", "integrate"},
                     {"seed", 3},
                     {"integrand", {{"expression", "exp(-x*x-y*y)"}}},
                     {"domain", {{"type", "box"}, {"lower", {0, 0}}, {"upper", {1, 1}}}},
                     {"stop", {{"max_samples", 20000000}}}};
  const std::string ref = m.submit(spec, 0)->id();
  ASSERT_TRUE(wait_until([&] { return status_of(m, ref) == JobStatus::succeeded; }, 120));

  const std::string low = m.submit(spec, 0, {}, /*use_cache=*/false)->id();
  ASSERT_TRUE(wait_until([&] { return passes_of(m, low) >= 1; }, 60));
  *armed = true;
  const std::string high = m.submit(fake_spec(kForever, 1, 99), 5)->id();
  ASSERT_TRUE(store->wait_until_a_save_is_held(60)) << "the low job's state is saved";
  ASSERT_TRUE(wait_until([&] { return status_of(m, high) == JobStatus::running; }, 20))
      << "the urgent job starts while the paused job's save is held";
  EXPECT_EQ(status_of(m, low), JobStatus::queued);
  EXPECT_EQ(m.snapshot(low).executor.waiting_reason, "preempted");
  EXPECT_TRUE(m.snapshot(low, JobManager::SnapshotOf::state).runner) << "in memory until stored";
  store->open();
  EXPECT_TRUE(wait_until([&] { return !m.snapshot(low, JobManager::SnapshotOf::state).runner; }, 30))
      << "stored, it leaves memory";
  m.cancel(high);
  ASSERT_TRUE(wait_until([&] { return status_of(m, low) == JobStatus::succeeded; }, 120));
  EXPECT_EQ(m.snapshot(low).final_result->at("bits"), m.snapshot(ref).final_result->at("bits"));
  m.shutdown();
}

TEST(Preemption, NotBeforeTheMinimumRunTimeAndNotForEqualPriority) {
  auto store = make_memory_store();
  JobManager m(one_slot(1.0), *store, compile_any);
  m.recover();
  const std::string low = m.submit(fake_spec(kForever, 1, 1), 0)->id();
  ASSERT_TRUE(wait_until([&] { return status_of(m, low) == JobStatus::running; }));
  const auto t0 = std::chrono::steady_clock::now();
  const std::string same = m.submit(fake_spec(kForever, 1, 2), 0)->id();
  const std::string high = m.submit(fake_spec(kForever, 1, 3), 5)->id();
  std::this_thread::sleep_for(std::chrono::milliseconds(400));
  if (std::chrono::steady_clock::now() - t0 < std::chrono::milliseconds(900)) {
    EXPECT_EQ(status_of(m, low), JobStatus::running) << "it has run less than the minimum run time";
  }
  ASSERT_TRUE(wait_until([&] { return status_of(m, high) == JobStatus::running; }, 30));
  EXPECT_EQ(m.snapshot(low).executor.waiting_reason, "preempted");
  EXPECT_EQ(status_of(m, same), JobStatus::queued);
  EXPECT_EQ(m.snapshot(same).executor.waiting_reason, "") << "never started, never preempted";
  // Equal priority never preempts: "high" keeps running while "low" and "same" wait.
  std::this_thread::sleep_for(std::chrono::milliseconds(1500));
  EXPECT_EQ(status_of(m, high), JobStatus::running);
  EXPECT_EQ(m.stats().preemptions, 1u);
  // It ends: "low" (submitted first) resumes, and a new priority-5 job must wait until
  // "low" has run its minimum time again.
  m.cancel(high);
  ASSERT_TRUE(wait_until([&] { return status_of(m, low) == JobStatus::running; }, 30));
  const auto resumed = std::chrono::steady_clock::now();
  const std::string urgent = m.submit(fake_spec(kForever, 1, 4), 5)->id();
  std::this_thread::sleep_for(std::chrono::milliseconds(400));
  if (std::chrono::steady_clock::now() - resumed < std::chrono::milliseconds(900)) {
    EXPECT_EQ(status_of(m, low), JobStatus::running) << "resumed less than the minimum run time ago";
  }
  ASSERT_TRUE(wait_until([&] { return status_of(m, urgent) == JobStatus::running; }, 30));
  EXPECT_EQ(m.stats().preemptions, 2u);
  for (const auto& id : {low, same, urgent}) m.cancel(id);
  m.shutdown();
}

TEST(Preemption, AnOwnerBelowItsFairSharePausesAnotherOwnersJob) {
  auto store = make_memory_store();
  ManagerConfig mc = one_slot(0);
  mc.max_running = 2;
  JobManager m(mc, *store, compile_any);
  m.recover();
  Submitter alice, bob;
  alice.owner = "alice";
  bob.owner = "bob";
  const std::string a1 = m.submit(fake_spec(kForever, 1, 1), 0, alice)->id();
  const std::string a2 = m.submit(fake_spec(kForever, 1, 2), 0, alice)->id();
  ASSERT_TRUE(wait_until([&] { return status_of(m, a2) == JobStatus::running; }));
  const std::string b1 = m.submit(fake_spec(kForever, 1, 3), 0, bob)->id();
  ASSERT_TRUE(wait_until([&] { return status_of(m, b1) == JobStatus::running; }, 30));
  EXPECT_EQ(status_of(m, a1), JobStatus::running);
  EXPECT_EQ(status_of(m, a2), JobStatus::queued) << "alice's newest job gives way";
  EXPECT_EQ(m.snapshot(a2).executor.waiting_reason, "preempted");
  // Each owner now has its share (1 of 2): nothing more is paused.
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  EXPECT_EQ(m.stats().preemptions, 1u);
  for (const auto& id : {a1, a2, b1}) m.cancel(id);
  m.shutdown();
}

}  // namespace
}  // namespace tally::test
