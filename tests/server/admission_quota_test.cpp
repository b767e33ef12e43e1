// Issue 27 N7: every path that makes state is admitted alike. A user at max_queued_jobs
// who extends finished jobs, or asks validate for a pilot, is refused exactly as a new
// submit is (403, the same detail); before, extend queued any number of jobs.
#include <gtest/gtest.h>

#include "server/auth/access_control.hpp"
#include "server/auth/auth_file.hpp"
#include "server/auth/token.hpp"
#include "server_test_support.hpp"

namespace tally::test {
namespace {

using nlohmann::json;

TEST(AdmissionQuota, ExtendAndValidateAreRefusedAsSubmitIsAtMaxQueued) {
  const std::string alice = generate_token();
  AuthFile f;
  Quotas q;
  q.max_running_jobs = 1;
  q.max_queued_jobs = 2;
  f.principals.push_back(PrincipalEntry{"alice", Role::user, token_sha256_hex(alice), q, {}});
  AccessControl access(f);
  HandlerConfig hc;
  hc.access.access = &access;
  ManagerConfig mc = test_manager_config(1);
  mc.max_running = 1;
  Harness h(mc, make_memory_store(), hc);
  const HttpRequest::Headers auth{{"authorization", "Bearer " + alice}};
  const auto as = [&](std::string method, std::string target, std::string body = {}) {
    return h.call(std::move(method), std::move(target), std::move(body), "application/json", auth);
  };
  const auto state = [&](const std::string& id) { return json::parse(as("GET", "/v1/jobs/" + id).body).at("state"); };
  std::vector<std::string> done;
  for (uint64_t seed = 1; seed <= 4; ++seed) {
    const HttpResponse r = as("POST", "/v1/jobs", fake_spec(2000, 0, seed).dump());
    ASSERT_EQ(r.status, 202) << r.body;
    done.push_back(json::parse(r.body).at("id"));
    ASSERT_TRUE(wait_until([&] { return state(done.back()) == "succeeded"; })) << done.back();
  }
  const HttpResponse lr = as("POST", "/v1/jobs", fake_spec(kForever, 1, 9).dump());
  ASSERT_EQ(lr.status, 202) << lr.body;
  const std::string running = json::parse(lr.body).at("id");
  ASSERT_TRUE(wait_until([&] { return state(running) == "running"; }));

  const std::string more = json{{"max_samples", 4000}}.dump();
  for (int i = 0; i < 2; ++i) {
    const HttpResponse e = as("POST", "/v1/jobs/" + done[i] + "/extend", more);
    EXPECT_EQ(e.status, 202) << e.body;
    EXPECT_EQ(state(done[i]), "queued");
  }
  const HttpResponse submit = as("POST", "/v1/jobs", fake_spec(100, 0, 10).dump());
  ASSERT_EQ(submit.status, 403) << submit.body;
  const std::string detail = json::parse(submit.body).at("detail");
  EXPECT_EQ(detail, "quota max_queued_jobs: \"alice\" already has 2 queued and 1 running jobs "
                    "(max_queued_jobs 2, max_running_jobs 1)");
  const HttpResponse extend = as("POST", "/v1/jobs/" + done[2] + "/extend", more);
  EXPECT_EQ(extend.status, 403) << extend.body;
  EXPECT_EQ(json::parse(extend.body).at("detail"), detail);
  EXPECT_EQ(state(done[2]), "succeeded") << "a refused extend leaves the job as it was";
  const HttpResponse validate = as("POST", "/v1/jobs/validate", fake_spec(100, 0, 11).dump());
  EXPECT_EQ(validate.status, 403) << validate.body;
  EXPECT_EQ(json::parse(validate.body).at("detail"), detail);

  // A slot frees: the extended jobs run on from their stored states and finish.
  as("DELETE", "/v1/jobs/" + running);
  for (int i = 0; i < 2; ++i) {
    EXPECT_TRUE(wait_until([&] { return state(done[i]) == "succeeded"; })) << done[i];
    EXPECT_EQ(h.manager->snapshot(done[i]).facts->samples, 4000u) << done[i];
  }
}

}  // namespace
}  // namespace tally::test

namespace tally::test {
namespace {

// Issue 32: jobs recovered at a restart are held to their owner's max_running like new
// ones. Three of alice's jobs run at shutdown (no quota then); after a restart where her
// quota is 1, one runs and two read queued with the reason (before: all three ran).
TEST(AdmissionQuota, RecoveredJobsAreHeldToTheirOwnersMaxRunning) {
  auto store = make_memory_store();
  ManagerConfig mc = test_manager_config(2);
  mc.max_running = 4;
  Submitter alice;
  alice.owner = "alice";
  std::vector<std::string> ids;
  {
    JobManager m(mc, *store, compile_fake_job);
    m.recover();
    for (uint64_t seed = 1; seed <= 3; ++seed) ids.push_back(m.submit(fake_spec(kForever, 1, seed), 0, alice)->id());
    ASSERT_TRUE(wait_until([&] {
      return std::all_of(ids.begin(), ids.end(), [&](const auto& id) { return m.snapshot(id).status == JobStatus::running; });
    }));
    m.shutdown();
  }
  JobManager m(mc, *store, compile_fake_job);
  m.recover([](const std::string& owner) { return owner == "alice" ? uint64_t{1} : UINT64_MAX; });
  const auto count = [&](JobStatus st) {
    return std::count_if(ids.begin(), ids.end(), [&](const auto& id) { return m.snapshot(id).status == st; });
  };
  ASSERT_TRUE(wait_until([&] { return count(JobStatus::running) == 1; }));
  std::this_thread::sleep_for(std::chrono::milliseconds(200));  // nothing else starts meanwhile
  EXPECT_EQ(count(JobStatus::running), 1);
  EXPECT_EQ(count(JobStatus::queued), 2);
  for (const auto& id : ids) {
    const JobSnapshot s = m.snapshot(id);
    if (s.status == JobStatus::queued) {
      EXPECT_EQ(s.executor.waiting_reason, "owner at max_running_jobs") << id;
    }
  }
  m.shutdown();
}

}  // namespace
}  // namespace tally::test
