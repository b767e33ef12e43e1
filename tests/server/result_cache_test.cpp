// Issue 32, the result cache: a submit whose canonical spec and seed equal a finished
// job's that the submitter may read is answered from the stored result (a new job id,
// cached_from, the same bits and state, nothing computed); ?cache=false, another seed
// or another spec computes; another tenant's result is never used; extend of a cached
// job goes on from the stored state.
#include "server/jobs/result_cache.hpp"

#include <gtest/gtest.h>

#include <cstring>

#include "common/engine/checkpoint.hpp"
#include "common/engine/results_version.hpp"

#include "server_test_support.hpp"

namespace tally::test {
namespace {

using nlohmann::json;

TEST(ResultCache, CanonicalTextIgnoresKeyOrderAndNumberForm) {
  const json a = json::parse(R"({"b": 1.0, "a": [2, 3e0, 0.10, -0.0], "c": {"y": 1e2, "x": "s"}})");
  const json b = json::parse(R"({"c": {"x": "s", "y": 100}, "a": [2.0, 3, 0.1, 0], "b": 1})");
  EXPECT_EQ(ResultCache::canonical(a), ResultCache::canonical(b));
  EXPECT_EQ(ResultCache::canonical(b), R"({"a":[2,3,0.1,0],"b":1,"c":{"x":"s","y":100}})");
  EXPECT_NE(ResultCache::canonical(json::parse(R"({"a": 1.5})")), ResultCache::canonical(json::parse(R"({"a": 1.25})")));
  EXPECT_NE(ResultCache::canonical(json::parse(R"({"a": "1"})")), ResultCache::canonical(json::parse(R"({"a": 1})")));
  EXPECT_NE(ResultCache::key_of(a, 1), ResultCache::key_of(a, 2));
  EXPECT_TRUE(ResultCache::reusable(StopReason::max_samples));
  EXPECT_TRUE(ResultCache::reusable(StopReason::error_target));
  EXPECT_FALSE(ResultCache::reusable(StopReason::time_budget));
  EXPECT_FALSE(ResultCache::reusable(StopReason::sample_cap));
  EXPECT_FALSE(ResultCache::reusable(StopReason::cancelled));
}

TEST(ResultCache, FindsTheNewestReadableSourceWithinTheSampleCap) {
  ResultCache c;
  c.add("k", "a1", "alice", 1000);
  c.add("k", "b1", "bob", 1000);
  EXPECT_EQ(c.find("k", "alice", false, 5000).value_or(""), "a1");
  EXPECT_EQ(c.find("k", "bob", false, 5000).value_or(""), "b1");
  EXPECT_FALSE(c.find("k", "carol", false, 5000));
  EXPECT_EQ(c.find("k", "root", true, 5000).value_or(""), "b1");
  EXPECT_FALSE(c.find("k", "alice", false, 999)) << "its sample cap would have stopped it sooner";
  EXPECT_FALSE(c.find("other", "alice", true, 5000));
  c.erase("a1");
  EXPECT_FALSE(c.find("k", "alice", false, 5000));
}

struct CacheHarness : Harness {
  CacheHarness() : Harness(config()) {}
  static ManagerConfig config() {
    ManagerConfig mc = test_manager_config(1);
    mc.max_running = 2;
    return mc;
  }
  json status(const std::string& id) { return call_json("GET", "/v1/jobs/" + id); }
  std::string done(const json& spec, const std::string& query = "") {
    const HttpResponse r = call("POST", "/v1/jobs" + query, spec.dump());
    if (r.status != 202) throw std::runtime_error("submit: " + r.body);
    const std::string id = json::parse(r.body).at("id");
    if (!wait_state(id, "succeeded")) throw std::runtime_error("did not succeed: " + id);
    return id;
  }
  double metric(const std::string& name) {
    const std::string body = call("GET", "/metrics").body;
    const size_t at = body.find("\n" + name + " ");
    if (at == std::string::npos) throw std::runtime_error("no metric " + name);
    return std::stod(body.substr(at + name.size() + 2));
  }
  std::vector<Tally> channels(const std::string& id) {
    const JobSnapshot s = manager->snapshot(id, JobManager::SnapshotOf::state);
    auto st = manager->state(s);
    return st ? st->channels : std::vector<Tally>{};
  }
};

bool same_bits(const std::vector<Tally>& a, const std::vector<Tally>& b) {
  return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(Tally)) == 0;
}

TEST(ResultCache, HitAnswersBitIdenticalWithoutComputing) {
  CacheHarness h;
  const json spec = fake_spec(40000, 20, 4, true);
  const std::string first = h.done(spec);
  const uint64_t computed = h.manager->stats().samples_total;
  // The same spec written otherwise: keys reordered, the seed as 4.0.
  json again = json::parse(R"({"stop": {"max_samples": 40000.0}, "seed": 4.0})");
  for (auto it = spec.begin(); it != spec.end(); ++it) {
    if (!again.contains(it.key())) again[it.key()] = it.value();
  }
  const auto t0 = std::chrono::steady_clock::now();
  const HttpResponse r = h.call("POST", "/v1/jobs", again.dump());
  const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  ASSERT_EQ(r.status, 202) << r.body;
  EXPECT_EQ(json::parse(r.body).at("state"), "succeeded") << "answered at once";
  const std::string second = json::parse(r.body).at("id");
  EXPECT_NE(second, first);
  const json s1 = h.status(first), s2 = h.status(second);
  EXPECT_EQ(s2.at("cached_from"), first);
  EXPECT_FALSE(s1.contains("cached_from"));
  EXPECT_EQ(s2.at("bits"), s1.at("bits"));
  EXPECT_EQ(s2.at("result"), s1.at("result"));
  const std::vector<Tally> c1 = h.channels(first), c2 = h.channels(second);
  ASSERT_EQ(c1.size(), 64u);
  ASSERT_EQ(c2.size(), c1.size());
  for (size_t i = 0; i < c1.size(); ++i) {
    ASSERT_EQ(c2[i].n, c1[i].n) << i;
    ASSERT_EQ(c2[i].mean, c1[i].mean) << i;
    ASSERT_EQ(c2[i].m2, c1[i].m2) << i;
  }
  EXPECT_TRUE(same_bits(c2, c1)) << "the stored state (its image) is the same";
  EXPECT_EQ(h.manager->stats().samples_total, computed) << "nothing was computed";
  EXPECT_EQ(h.metric("tally_result_cache_hits_total"), 1);
  EXPECT_EQ(h.metric("tally_result_cache_misses_total"), 1);  // the first submit looked
  std::printf("cached submit answered in %.2f ms\n", ms);
  // The list shows where it came from.
  bool listed = false;
  const json list = h.call_json("GET", "/v1/jobs");
  for (const json& j : list.at("jobs")) {
    if (j.at("id") == second) listed = j.at("cached_from") == first;
  }
  EXPECT_TRUE(listed) << list.dump();
}

TEST(ResultCache, OptOutAnotherSeedOrAnotherSpecComputes) {
  CacheHarness h;
  const json spec = fake_spec(20000, 0, 4);
  h.done(spec);
  uint64_t computed = h.manager->stats().samples_total;
  const auto computes = [&](const json& s, const std::string& query) {
    const std::string id = h.done(s, query);
    const uint64_t now = h.manager->stats().samples_total;
    const bool grew = now > computed;
    computed = now;
    return grew && !h.status(id).contains("cached_from");
  };
  EXPECT_TRUE(computes(spec, "?cache=false"));
  EXPECT_TRUE(computes(fake_spec(20000, 0, 5), ""));  // another seed
  EXPECT_TRUE(computes(fake_spec(24000, 0, 4), ""));  // another spec
  EXPECT_EQ(h.metric("tally_result_cache_hits_total"), 0);
  EXPECT_EQ(h.metric("tally_result_cache_misses_total"), 3);  // the opt-out did not look
  EXPECT_EQ(h.call("POST", "/v1/jobs?cache=maybe", spec.dump()).status, 400);
}

TEST(ResultCache, NeverCrossesTenants) {
  auto store = make_memory_store();
  ManagerConfig mc = test_manager_config(1);
  JobManager m(mc, *store, compile_fake_job);
  m.recover();
  const auto who = [](const std::string& owner, bool reads_all) {
    Submitter s;
    s.owner = owner;
    s.reads_all = reads_all;
    return s;
  };
  const Submitter alice = who("alice", false), bob = who("bob", false), root = who("root", true);
  const json spec = fake_spec(20000, 0, 8);
  const std::string a = m.submit(spec, 0, alice)->id();
  ASSERT_TRUE(wait_until([&] { return m.snapshot(a).status == JobStatus::succeeded; }));
  const auto b = m.submit(spec, 0, bob);
  EXPECT_EQ(m.snapshot(b->id()).cached_from, "") << "bob may not read alice's job";
  // Bob's job computes; it is finished and stored before alice asks again, so which
  // source is the newest does not depend on how fast it ran (it once finished after a2
  // under the sanitizers, and then it was the newest).
  ASSERT_TRUE(wait_until([&] { return m.snapshot(b->id()).status == JobStatus::succeeded; }));
  const auto a2 = m.submit(spec, 0, alice);
  EXPECT_EQ(m.snapshot(a2->id()).cached_from, a) << "alice may not read bob's job";
  const auto r = m.submit(spec, 0, root);
  EXPECT_EQ(m.snapshot(r->id()).cached_from, a2->id()) << "an admin may read every job: the newest source";
  m.shutdown();
}

TEST(ResultCache, ExtendOfACachedJobGoesOnFromTheStoredState) {
  CacheHarness h;
  const json spec = fake_spec(20000, 0, 6, true);
  const std::string first = h.done(spec);
  const HttpResponse r = h.call("POST", "/v1/jobs", spec.dump());
  const std::string cached = json::parse(r.body).at("id");
  ASSERT_EQ(h.status(cached).at("cached_from"), first);
  for (const std::string& id : {first, cached}) {
    const HttpResponse e = h.call("POST", "/v1/jobs/" + id + "/extend", R"({"max_samples": 50000})");
    ASSERT_EQ(e.status, 202) << e.body;
  }
  ASSERT_TRUE(h.wait_state(first, "succeeded"));
  ASSERT_TRUE(h.wait_state(cached, "succeeded"));
  EXPECT_EQ(h.status(cached).at("samples"), h.status(first).at("samples"));
  EXPECT_EQ(h.status(cached).at("bits"), h.status(first).at("bits"));
  EXPECT_TRUE(same_bits(h.channels(cached), h.channels(first)));
  // Extended, the first job's result changed: it answers no submit of the old spec now;
  // the cached job (extended too) neither. A new submit computes.
  const HttpResponse again = h.call("POST", "/v1/jobs", spec.dump());
  EXPECT_FALSE(h.status(json::parse(again.body).at("id")).contains("cached_from"));
}


// Runs `specs` to succeeded in a manager on `store` that then stops (as at a restart);
// their ids in order.
std::vector<std::string> run_and_stop(JobStore& store, const std::vector<json>& specs) {
  JobManager m(test_manager_config(1), store, compile_fake_job);
  m.recover();
  std::vector<std::string> ids;
  for (const json& spec : specs) ids.push_back(m.submit(spec, 0, {})->id());
  for (const auto& id : ids) {
    if (!wait_until([&] { return m.snapshot(id).status == JobStatus::succeeded; })) {
      throw std::runtime_error("did not succeed: " + id);
    }
  }
  m.shutdown();
  return ids;
}

// A finished job computed by another generation of the engine (after an upgrade that
// changed the bits of a spec and seed) answers no submit: its stored facts and state
// carry the results version they were computed with, and recovery keeps only jobs of
// this build's version as sources. Before the fix the key was the spec and seed alone,
// and `make demo` served a glTF render from before the default BRDF changed.
TEST(ResultCache, JobsOfAnotherResultsVersionAnswerNoSubmit) {
  auto store = make_memory_store();
  const ManagerConfig mc = test_manager_config(1);
  const json spec = fake_spec(20000, 0, 11), other = fake_spec(20000, 0, 12);
  const std::vector<std::string> ids = run_and_stop(*store, {spec, other});
  const std::string old_id = ids[0], current_id = ids[1];
  // Rewrite the first job as an older build stored it: facts without a results
  // version, a state of version 0.
  for (StoredJob row : store->load_all()) {
    if (row.id != old_id) continue;
    json facts = json::parse(row.facts);
    ASSERT_EQ(facts.at("results_version"), kResultsVersion);
    facts.erase("results_version");
    row.facts = facts.dump();
    JobState state = decode_checkpoint(store->load_checkpoint(old_id).value());
    state.results_version = 0;
    row.checkpoint = encode_checkpoint(state);
    store->save(row);
  }
  JobManager m(mc, *store, compile_fake_job);
  m.recover();
  EXPECT_EQ(m.snapshot(old_id).status, JobStatus::succeeded) << "still readable";
  EXPECT_EQ(m.snapshot(old_id).facts->results_version, 0u);
  // The job of this version answers; the older one does not, and the job computed in
  // its place answers the next submit.
  EXPECT_EQ(m.snapshot(m.submit(other, 0, {})->id()).cached_from, current_id);
  const uint64_t before = m.stats().samples_total;
  const auto fresh = m.submit(spec, 0, {});
  EXPECT_EQ(m.snapshot(fresh->id()).cached_from, "");
  ASSERT_TRUE(wait_until([&] { return m.snapshot(fresh->id()).status == JobStatus::succeeded; }));
  EXPECT_EQ(m.stats().samples_total, before + 20000) << "computed, not answered";
  EXPECT_EQ(m.snapshot(m.submit(spec, 0, {})->id()).cached_from, fresh->id());
  m.shutdown();
}

// A job interrupted by a restart resumes from its checkpoint; if that state was
// computed by another version, the finished job keeps that version (its bits are a mix)
// and answers no submit.
TEST(ResultCache, JobResumedFromAnotherVersionsStateAnswersNoSubmit) {
  auto store = make_memory_store();
  const ManagerConfig mc = test_manager_config(1);
  const json spec = fake_spec(40000, 0, 13), half = fake_spec(20000, 0, 13);
  const std::vector<std::string> ids = run_and_stop(*store, {spec, half});
  const std::string id = ids[0], half_id = ids[1];
  // Stored as an older build left it when killed half-way: running, with a state of
  // version 0 at 20,000 of its 40,000 samples (the same kernel's state at that point).
  JobState state = decode_checkpoint(store->load_checkpoint(half_id).value());
  ASSERT_EQ(state.results_version, kResultsVersion);
  ASSERT_EQ(state.samples, 20000u);
  state.results_version = 0;
  for (StoredJob row : store->load_all()) {
    if (row.id == half_id) store->remove(half_id);
    if (row.id != id) continue;
    row.state = "running";
    row.result.clear();
    row.facts.clear();
    row.finished_at = 0;
    row.checkpoint = encode_checkpoint(state);
    store->save(row);
  }
  JobManager m(mc, *store, compile_fake_job);
  m.recover();
  ASSERT_TRUE(wait_until([&] { return m.snapshot(id).status == JobStatus::succeeded; }));
  ASSERT_TRUE(m.snapshot(id).facts);
  EXPECT_EQ(m.snapshot(id).facts->samples, 40000u) << "it ran the second half";
  EXPECT_EQ(m.snapshot(id).facts->results_version, 0u);
  EXPECT_EQ(m.snapshot(m.submit(spec, 0, {})->id()).cached_from, "");
  m.shutdown();
}

// A job stored as running whose state already meets its rule (killed after its last
// pass, before its final save) finishes at start without a pass: once stored it answers
// later submits and its state leaves memory, as any finished job's.
TEST(ResultCache, JobRestoredAlreadyCompleteAnswersAndLeavesMemory) {
  auto store = make_memory_store();
  const json spec = fake_spec(20000, 0, 14);
  const std::string id = run_and_stop(*store, {spec})[0];
  for (StoredJob row : store->load_all()) {
    row.state = "running";
    row.result.clear();
    row.facts.clear();
    row.finished_at = 0;
    store->save(row);  // the checkpoint is kept: the whole state, 20,000 samples
  }
  JobManager m(test_manager_config(1), *store, compile_fake_job);
  m.recover();
  ASSERT_TRUE(wait_until([&] { return m.snapshot(id).status == JobStatus::succeeded; }));
  EXPECT_TRUE(wait_until([&] { return m.stats().memory_used == 0; }, 5)) << m.stats().memory_used << " bytes held";
  EXPECT_EQ(m.snapshot(m.submit(spec, 0, {})->id()).cached_from, id);
  m.shutdown();
}

}  // namespace
}  // namespace tally::test
