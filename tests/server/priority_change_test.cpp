// PATCH /v1/jobs/{id} {"priority": n}: a queued or running job's priority changes after
// submit (issue 30, the page's priority control). Exact statuses (200 with the job's
// summary, 404, 409 finished, 422 naming the field, 415, 400), and the change takes
// effect: a queued job moves in the queue, a raised one preempts a lower running one,
// the executor charges the new weight, and the store keeps it across a restart.
#include <gtest/gtest.h>

#include <filesystem>

#include <unistd.h>

#include "server/executor/in_process_executor.hpp"
#include "server_test_support.hpp"

namespace tally::test {
namespace {

using nlohmann::json;

std::string pointer_of(const HttpResponse& r) {
  const json p = json::parse(r.body);
  return p.value("pointer", std::string("(none)"));
}

HttpResponse patch(Harness& h, const std::string& id, const std::string& body,
                   const std::string& content_type = "application/json") {
  return h.call("PATCH", "/v1/jobs/" + id, body, content_type);
}

ManagerConfig one_slot(double preempt_min_run_s) {
  ManagerConfig mc = test_manager_config(1);
  mc.max_running = 1;
  mc.preempt_min_run_s = preempt_min_run_s;
  return mc;
}

TEST(PriorityChange, ExactStatusesAndTheJobsSummary) {
  Harness h(one_slot(-1));
  const std::string running = h.submit(fake_spec(kForever, 1));
  ASSERT_TRUE(h.wait_state(running, "running"));
  const std::string queued = h.submit(fake_spec(kForever, 1, 2));
  ASSERT_EQ(h.state(queued), "queued");

  for (const auto& [id, p] : std::vector<std::pair<std::string, int>>{{running, 3}, {queued, -5}, {queued, 5}}) {
    const HttpResponse r = patch(h, id, json{{"priority", p}}.dump());
    ASSERT_EQ(r.status, 200) << r.body;
    EXPECT_EQ(r.header("content-type"), "application/json");
    const json body = json::parse(r.body);
    EXPECT_EQ(body.at("id"), id);
    EXPECT_EQ(body.at("priority"), p);
    EXPECT_EQ(h.call_json("GET", "/v1/jobs/" + id).at("priority"), p) << "the status document follows at once";
  }
  // The list shows it too.
  const json list = h.call_json("GET", "/v1/jobs");  // the loop reads into it: keep it alive
  for (const json& j : list.at("jobs")) {
    EXPECT_EQ(j.at("priority"), j.at("id") == running ? 3 : 5);
  }

  const HttpResponse missing = patch(h, "0123456789abcdef", R"({"priority": 1})");
  EXPECT_EQ(missing.status, 404) << missing.body;
  EXPECT_EQ(json::parse(missing.body).at("detail"), "no job with id \"0123456789abcdef\"");

  // Bad bodies: 422 naming the field, for the running job and with nothing changed.
  const std::vector<std::pair<std::string, std::string>> bad = {
      {R"({"priority": 6})", "/priority"},        {R"({"priority": -6})", "/priority"},
      {R"({"priority": 1.5})", "/priority"},      {R"({"priority": "high"})", "/priority"},
      {R"({"priority": null})", "/priority"},     {R"({"priority": 18446744073709551615})", "/priority"},
      {R"({"priority": 1, "name": "x"})", "/name"}, {R"({})", ""},
      {R"([1])", ""}};
  for (const auto& [body, pointer] : bad) {
    const HttpResponse r = patch(h, running, body);
    EXPECT_EQ(r.status, 422) << body << ": " << r.body;
    EXPECT_EQ(r.header("content-type"), "application/problem+json") << body;
    EXPECT_EQ(pointer_of(r), pointer) << body << ": " << r.body;
  }
  EXPECT_EQ(json::parse(patch(h, running, R"({"priority": 9})").body).at("detail"), "must be in [-5, 5], got 9");
  EXPECT_EQ(h.call_json("GET", "/v1/jobs/" + running).at("priority"), 3) << "a refused change changes nothing";
  EXPECT_EQ(patch(h, running, R"({"priority": 1})", "text/plain").status, 415);
  EXPECT_EQ(patch(h, running, R"({"priority": )").status, 400);

  // Finished: 409, whatever the value.
  ASSERT_EQ(h.call("DELETE", "/v1/jobs/" + queued).status, 200);  // a queued job is cancelled at once
  const HttpResponse done = patch(h, queued, R"({"priority": 2})");
  EXPECT_EQ(done.status, 409) << done.body;
  EXPECT_EQ(json::parse(done.body).at("detail"),
            "job " + queued + " has already finished (cancelled); its priority no longer changes anything");
  EXPECT_EQ(h.call_json("GET", "/v1/jobs/" + queued).at("priority"), 5);
  h.call("DELETE", "/v1/jobs/" + running);
}

// One running slot, preemption off: B and C wait at priority 0 (B first, by submission);
// raising C puts it first, so it starts when the slot frees and B still waits.
TEST(PriorityChange, AQueuedJobMovesInTheQueue) {
  Harness h(one_slot(-1));
  const std::string a = h.submit(fake_spec(kForever, 1, 1));
  ASSERT_TRUE(h.wait_state(a, "running"));
  const std::string b = h.submit(fake_spec(kForever, 1, 2));
  const std::string c = h.submit(fake_spec(kForever, 1, 3));
  ASSERT_EQ(h.call("PATCH", "/v1/jobs/" + c, R"({"priority": 2})").status, 200);
  EXPECT_EQ(h.state(a), "running") << "preemption is off: the running job keeps its slot";
  ASSERT_EQ(h.call("DELETE", "/v1/jobs/" + a).status / 100, 2);
  ASSERT_TRUE(h.wait_state(c, "running", 20)) << "the raised job starts first";
  EXPECT_EQ(h.state(b), "queued");
  // Lowering it below B's: B goes before it from then on.
  ASSERT_EQ(h.call("PATCH", "/v1/jobs/" + c, R"({"priority": -1})").status, 200);
  ASSERT_EQ(h.call("DELETE", "/v1/jobs/" + c).status / 100, 2);
  ASSERT_TRUE(h.wait_state(b, "running", 20));
  h.call("DELETE", "/v1/jobs/" + b);
}

// Preemption on (no minimum run): a waiting job of equal priority does not pause the
// running one; raised above it, it does at the running job's next pass boundary.
TEST(PriorityChange, ARaisedQueuedJobPreemptsALowerRunningOne) {
  Harness h(one_slot(0));
  const std::string low = h.submit(fake_spec(kForever, 1, 1));
  ASSERT_TRUE(h.wait_state(low, "running"));
  const std::string waiting = h.submit(fake_spec(kForever, 1, 2));
  std::this_thread::sleep_for(std::chrono::milliseconds(300));  // many pass boundaries of `low`
  ASSERT_EQ(h.state(waiting), "queued") << "equal priorities never preempt";
  ASSERT_EQ(h.call("PATCH", "/v1/jobs/" + waiting, R"({"priority": 1})").status, 200);
  ASSERT_TRUE(h.wait_state(waiting, "running", 20));
  const json s = h.call_json("GET", "/v1/jobs/" + low);
  EXPECT_EQ(s.at("state"), "queued");
  EXPECT_EQ(s.at("waiting_reason"), "preempted");
  h.call("DELETE", "/v1/jobs/" + waiting);
  h.call("DELETE", "/v1/jobs/" + low);
}

// The in-process executor charges a chunk's run time divided by the job's weight,
// priority + 6: the change reaches it (the weight of the job's next chunks).
TEST(PriorityChange, TheExecutorChargesTheNewWeight) {
  InProcessExecutor* executor = nullptr;
  ManagerConfig mc = test_manager_config(1);
  mc.make_executor = [&](ExecutorCallbacks cb) {
    auto e = std::make_unique<InProcessExecutor>(1, std::move(cb), mc.chunk_target_s);
    executor = e.get();
    return e;
  };
  Harness h(mc);
  ASSERT_NE(executor, nullptr);
  const std::string id = h.submit(fake_spec(kForever, 1));
  ASSERT_TRUE(h.wait_state(id, "running"));
  EXPECT_EQ(executor->weight_of(id), 6.0);
  ASSERT_EQ(h.call("PATCH", "/v1/jobs/" + id, R"({"priority": 5})").status, 200);
  EXPECT_EQ(executor->weight_of(id), 11.0);
  ASSERT_EQ(h.call("PATCH", "/v1/jobs/" + id, R"({"priority": -5})").status, 200);
  EXPECT_EQ(executor->weight_of(id), 1.0);
  h.call("DELETE", "/v1/jobs/" + id);
}

// The stored row carries the new priority: after a restart the job resumes with it.
TEST(PriorityChange, TheStoreKeepsItAcrossARestart) {
  const std::filesystem::path dir =
      std::filesystem::temp_directory_path() / ("tally_priority_test_" + std::to_string(::getpid()));
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  std::string id;
  {
    Harness h(one_slot(-1), open_sqlite_store(dir.string()));
    const std::string running = h.submit(fake_spec(kForever, 1, 1));
    ASSERT_TRUE(h.wait_state(running, "running"));
    id = h.submit(fake_spec(kForever, 1, 2));
    ASSERT_EQ(h.call("PATCH", "/v1/jobs/" + id, R"({"priority": -4})").status, 200);
  }
  {
    Harness h(one_slot(-1), open_sqlite_store(dir.string()));
    EXPECT_EQ(h.call_json("GET", "/v1/jobs/" + id).at("priority"), -4);
  }
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace tally::test
