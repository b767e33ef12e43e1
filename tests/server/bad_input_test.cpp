// Wrong answers to bad input, each reproduced first: a pilot that hid the failure
// the job would hit, numbers out of double range, expression errors.
#include <gtest/gtest.h>

#include "common/engine/pass_loop.hpp"
#include "common/protocol/job_kinds.hpp"
#include "server/api/pilot.hpp"
#include "server_test_support.hpp"

namespace tally::test {
namespace {

using nlohmann::json;

// validate called `0/0` valid with a pilot mean of 0, while the real job fails at sample 0.
TEST(Pilot, ReportsTheFailureTheJobWouldHit) {
  const json spec = {{"kind", "integrate"},
                     {"integrand", {{"expression", "0/0"}}},
                     {"domain", {{"type", "interval"}, {"lower", 0}, {"upper", 1}}},
                     {"stop", {{"max_samples", 1000}}}};
  const auto def = compile_job(spec, JobLimits{});
  PilotOptions po;
  po.seconds = 0.05;
  const json p = run_pilot(*def, po);
  ASSERT_TRUE(p["pilot"].contains("error")) << p.dump();
  EXPECT_TRUE(p["prediction"].is_null());
  JobRunner runner(def->kernel(), def->stop_rule(), JobCaps{});
  run_local(runner, 1);
  EXPECT_EQ(runner.stop_reason(), StopReason::failed);
  ASSERT_TRUE(runner.error_message());
  EXPECT_EQ(p["pilot"]["error"].get<std::string>(), *runner.error_message());

  // Through the route: 422, not "valid": true.
  auto store = make_memory_store();
  JobManager manager(test_manager_config(), *store, compile_job);
  manager.recover();
  Metrics metrics;
  HandlerConfig hc;
  hc.pilot_seconds = 0.05;
  RequestHandler handler(manager, metrics, hc);
  HttpRequest r;
  r.method = "POST";
  r.target = "/v1/jobs/validate";
  r.headers.emplace_back("content-type", "application/json");
  r.body = spec.dump();
  const HttpResponse res = handler.handle(r);
  EXPECT_EQ(res.status, 422) << res.body;
  EXPECT_NE(res.body.find(*runner.error_message()), std::string::npos) << res.body;
  manager.shutdown();
}

// A number out of double range made nlohmann throw out_of_range -> 500.
TEST(RequestHandlerBadInput, NumberOutOfRangeIs400NamingTheField) {
  Harness h;
  for (const char* target : {"/v1/jobs", "/v1/jobs/validate"}) {
    const auto r = h.call("POST", target, R"({"kind": "fake", "stop": {"max_samples": 1e400}})");
    EXPECT_EQ(r.status, 400) << r.body;
    const json p = json::parse(r.body);
    EXPECT_EQ(p.value("pointer", ""), "/stop/max_samples") << r.body;
  }
  const auto arr = h.call("POST", "/v1/jobs", R"({"a": [1, 2, -1e999]})");
  EXPECT_EQ(arr.status, 400);
  EXPECT_EQ(json::parse(arr.body).value("pointer", ""), "/a/2") << arr.body;
  const auto top = h.call("POST", "/v1/jobs", "1e400");
  EXPECT_EQ(top.status, 400) << top.body;
}

}  // namespace
}  // namespace tally::test
