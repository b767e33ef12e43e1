// Issue 31: a vector integrand's progress events summarise its components (count, how
// many meet the target, the worst one), so thousands of components stream as one line;
// a scalar job's events carry no such field.
#include <gtest/gtest.h>

#include <vector>

#include "server_test_support.hpp"

namespace tally::test {
namespace {

using nlohmann::json;

json lattice_job(json integrand) {
  return {{"kind", "integrate"},
          {"seed", 5},
          {"integrand", std::move(integrand)},
          {"domain", {{"type", "box"}, {"lower", {0.0}}, {"upper", {1.0}}}},
          {"estimator", {{"type", "lattice"}, {"points", 31}}},
          {"stop", {{"max_samples", 64}, {"min_samples", 16}, {"rel_error", 1e-9}}}};
}

// The last progress event of a finished job, parsed.
json last_progress(JobManager& m, const json& spec) {
  const std::string id = m.submit(spec)->id();
  EXPECT_TRUE(wait_until([&] { return is_terminal(m.snapshot(id).status); }));
  EXPECT_EQ(m.snapshot(id).status, JobStatus::succeeded);
  const EventLog& log = m.find(id)->events();
  json last;
  for (const Event& e : log.read_after(log.first_id() - 1, 100000).events) {
    if (e.type == "progress") last = json::parse(e.data);
  }
  return last;
}

TEST(VectorProgress, ProgressEventsSummariseTheComponents) {
  ManagerConfig mc = test_manager_config(1);
  auto store = make_memory_store();
  JobManager m(mc, *store, compile_any);
  m.recover();
  std::vector<double> p;
  for (int i = 0; i < 50; ++i) p.push_back(0.5 + 0.1 * i);
  const json vec = last_progress(m, lattice_job({{"expression", "x0^p"}, {"parameters", {{"p", p}}}}));
  ASSERT_TRUE(vec.contains("components")) << vec.dump();
  const json& c = vec["components"];
  EXPECT_EQ(c["count"], 50);
  // A 1e-9 relative target is out of reach of 64 shifts of 31 points for x^p, p not an
  // integer-friendly exponent: none meet it, and the worst is named with its half-width.
  EXPECT_EQ(c["met"], 0);
  EXPECT_LT(c["worst"]["index"].get<int>(), 50);
  EXPECT_GT(c["worst"]["rel_half_width"].get<double>(), 1e-9);
  const json one = last_progress(m, lattice_job({{"expression", "x0^0.5"}}));
  EXPECT_FALSE(one.contains("components")) << one.dump();
  EXPECT_TRUE(one.contains("pass")) << one.dump();
  m.shutdown();
}

}  // namespace
}  // namespace tally::test
