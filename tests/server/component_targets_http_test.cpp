// Per-component error targets (issue 31) through the request handler: a bad list is a 422
// naming the field (the run, extend and restart: Recovery.ComponentTargetsKeptAcross...
// in store_test.cpp).
#include <gtest/gtest.h>

#include <vector>

#include "server_test_support.hpp"

namespace tally::test {
namespace {

using nlohmann::json;

TEST(ComponentTargetsHttp, BadTargetsAre422NamingTheField) {
  Harness h(test_manager_config(), make_memory_store(), {}, compile_any);
  // x^p for three values of p; two targets.
  const json spec = {{"kind", "integrate"},
                     {"integrand", {{"expression", "x0^p"}, {"parameters", {{"p", {1, 2, 3}}}}}},
                     {"domain", {{"type", "interval"}, {"lower", 0}, {"upper", 1}}},
                     {"stop", {{"max_samples", 1000}, {"component_targets", {{"rel_error", {1e-2, 4e-2}}}}}}};
  for (const char* target : {"/v1/jobs", "/v1/jobs/validate"}) {
    const auto r = h.call("POST", target, spec.dump());
    EXPECT_EQ(r.status, 422) << r.body;
    const json p = json::parse(r.body);
    EXPECT_EQ(p.value("pointer", ""), "/stop/component_targets/rel_error") << r.body;
    EXPECT_EQ(p.value("detail", ""), "has 2 entries; the integrand has 3 components") << r.body;
  }
  // An extend sets the job-wide targets; the job keeps its component targets.
  json ok = spec;
  ok["stop"]["component_targets"]["rel_error"] = {1e-2, 4e-2, 4e-2};
  const std::string id = h.submit(ok);
  ASSERT_TRUE(h.wait_state(id, "succeeded"));
  const auto r = h.call("POST", "/v1/jobs/" + id + "/extend",
                        R"({"max_samples": 2000, "component_targets": {"rel_error": [1, 1, 1]}})");
  EXPECT_EQ(r.status, 422) << r.body;
  EXPECT_EQ(json::parse(r.body).value("pointer", ""), "/component_targets") << r.body;

  // A null entry falls back on the job-wide rel_error: an extend that drops it is a 422
  // naming /rel_error, the job stays as it was, and the same extend with it is accepted.
  json nulls = spec;
  nulls["stop"]["component_targets"]["rel_error"] = {1e-2, nullptr, 4e-2};
  nulls["stop"]["rel_error"] = 5e-2;
  const std::string nid = h.submit(nulls);
  ASSERT_TRUE(h.wait_state(nid, "succeeded"));
  const auto dropped = h.call("POST", "/v1/jobs/" + nid + "/extend", R"({"max_samples": 2000})");
  EXPECT_EQ(dropped.status, 422) << dropped.body;
  EXPECT_EQ(json::parse(dropped.body).value("pointer", ""), "/rel_error") << dropped.body;
  const auto after = h.call("GET", "/v1/jobs/" + nid);
  EXPECT_EQ(json::parse(after.body).value("state", ""), "succeeded") << after.body;
  const auto kept = h.call("POST", "/v1/jobs/" + nid + "/extend", R"({"max_samples": 2000, "rel_error": 0.05})");
  EXPECT_EQ(kept.status, 202) << kept.body;
}

}  // namespace
}  // namespace tally::test
