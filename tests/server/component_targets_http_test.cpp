// Per-component error targets (issue 31) through the request handler: a bad list is a 422
// naming the field (the run, extend and restart: Recovery.ComponentTargetsKeptAcross...
// in store_test.cpp).
#include <gtest/gtest.h>

#include <vector>

#include "server_test_support.hpp"

namespace tally::test {
namespace {

using nlohmann::json;

// x, x^2, x^3 over [0, 1] with only component targets.
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
  spec["stop"]["component_targets"] = {{"rel_error", {1e-2, 4e-2}}};
  for (const char* target : {"/v1/jobs", "/v1/jobs/validate"}) {
    const auto r = h.call("POST", target, spec.dump());
    EXPECT_EQ(r.status, 422) << r.body;
    const json p = json::parse(r.body);
    EXPECT_EQ(p.value("pointer", ""), "/stop/component_targets/rel_error") << r.body;
    EXPECT_EQ(p.value("detail", ""), "has 2 entries; the integrand has 3 components") << r.body;
  }
}

}  // namespace
}  // namespace tally::test
