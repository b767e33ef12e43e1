// Per-component error targets (issue 31) through the request handler: a bad list is a 422
// naming the field; a job that max_samples stops first reports its unmet components; an
// extend keeps the targets, and a restart reads them back from the stored rule.
#include <gtest/gtest.h>

#include <vector>

#include "server_test_support.hpp"

namespace tally::test {
namespace {

using nlohmann::json;

// x, x^2, x^3 over [0, 1] on the frozen-grid (uniform) VEGAS kernel; only component
// targets, no job-wide one: x needs ~13k samples for 1e-2 relative, x^2 ~85k for 2e-3
// absolute, x^3 ~3k for 4e-2 relative.
json powers_job(uint64_t max_samples) {
  return {{"kind", "integrate"},
          {"seed", 9},
          {"integrand", {{"expressions", {"x0", "x0^2", "x0^3"}}}},
          {"domain", {{"type", "box"}, {"lower", {0.0}}, {"upper", {1.0}}}},
          {"estimator", {{"type", "uniform"}}},
          {"stop",
           {{"max_samples", max_samples},
            {"component_targets", {{"abs_error", {nullptr, 2e-3, nullptr}}, {"rel_error", {1e-2, nullptr, 4e-2}}}}}}};
}

TEST(ComponentTargetsHttp, BadTargetsAre422NamingTheField) {
  Harness h(test_manager_config(), make_memory_store(), {}, compile_any);
  json spec = powers_job(1000);
  spec["stop"]["component_targets"]["rel_error"] = {1e-2, 4e-2};
  for (const char* target : {"/v1/jobs", "/v1/jobs/validate"}) {
    const auto r = h.call("POST", target, spec.dump());
    EXPECT_EQ(r.status, 422) << r.body;
    const json p = json::parse(r.body);
    EXPECT_EQ(p.value("pointer", ""), "/stop/component_targets/rel_error") << r.body;
    EXPECT_NE(r.body.find("has 2 entries; the integrand has 3 components"), std::string::npos) << r.body;
  }
}

TEST(ComponentTargetsHttp, UnmetAtMaxSamplesThenExtendedToTheTargetsAcrossARestart) {
  TempDir dir;
  std::string id;
  json before;
  const json rule = powers_job(1).at("stop").at("component_targets");
  {
    Harness h(test_manager_config(), open_sqlite_store(dir.path.string()), {}, compile_any);
    id = h.submit(powers_job(20000));
    ASSERT_TRUE(h.wait_state(id, "succeeded"));
    const json s = h.call_json("GET", "/v1/jobs/" + id);
    EXPECT_EQ(s.at("stop_reason"), "max_samples") << s.dump();
    EXPECT_EQ(s.at("target_met"), false);
    // 20000 samples: x (~13k) and x^3 (~3k) meet theirs, x^2 (~85k) does not.
    const json& cs = s.at("result").at("components_summary");
    EXPECT_EQ(cs.at("met"), 2) << cs.dump();
    EXPECT_EQ(cs.at("unmet"), json::parse(R"({"count": 1, "first": [1]})")) << cs.dump();
    EXPECT_EQ(cs.at("worst").at("index"), 1);
    EXPECT_EQ(s.at("stop_rule").at("component_targets"), rule) << s.dump();
    ASSERT_EQ(h.call("POST", "/v1/jobs/" + id + "/extend", R"({"max_samples": 4000000})").status, 202);
    ASSERT_TRUE(h.wait_state(id, "succeeded", 60));
    before = h.call_json("GET", "/v1/jobs/" + id);
    EXPECT_EQ(before.at("stop_reason"), "error_target") << before.dump();
    EXPECT_EQ(before.at("target_met"), true);
    EXPECT_EQ(before.at("result").at("components_summary").at("met"), 3);
    EXPECT_FALSE(before.at("result").at("components_summary").contains("unmet"));
    EXPECT_LT(before.at("samples").get<uint64_t>(), 4000000u);
    EXPECT_EQ(before.at("stop_rule").at("component_targets"), rule);
    EXPECT_EQ(before.at("stop_rule").at("max_samples"), 4000000);
  }
  Harness h(test_manager_config(), open_sqlite_store(dir.path.string()), {}, compile_any);
  const json after = h.call_json("GET", "/v1/jobs/" + id);
  EXPECT_EQ(after.at("stop_rule"), before.at("stop_rule"));
  EXPECT_EQ(after.at("samples"), before.at("samples"));
  EXPECT_EQ(after.at("bits"), before.at("bits"));
  EXPECT_EQ(after.at("result").at("components_summary"), before.at("result").at("components_summary"));
}

}  // namespace
}  // namespace tally::test
