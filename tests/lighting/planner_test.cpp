// The planner switches effects off only where that cannot change the answer: each case
// runs the planned job and a forced "plan": "full" job on the same scene and seed.
#include <gtest/gtest.h>

#include "lighting/lighting_test_support.hpp"

namespace tally::test {
namespace {

json effect(const JobRun& r, const std::string& name) {
  const json plan = plan_json(*r.job);
  for (const json& e : plan["plan"]["effects"]) {
    if (e["effect"] == name) return e;
  }
  ADD_FAILURE() << "no effect " << name;
  return {};
}

void expect_same_answer(const JobRun& a, const JobRun& b) {
  const auto& ca = a.runner->state().channels;
  const auto& cb = b.runner->state().channels;
  ASSERT_EQ(ca.size(), cb.size());
  for (size_t i = 0; i < ca.size(); ++i) {
    const double se = std::hypot(ca[i].std_error(), cb[i].std_error());
    EXPECT_LE(std::fabs(ca[i].mean - cb[i].mean), 4 * se + 1e-12) << "channel " << i;
  }
}

TEST(Planner, SingleConvexLightNeedsNoShadowRays) {
  const json scene = {{"materials", {{"lamp", emitter(2.0)}}},
                      {"shapes", json::array({{{"type", "quad"}, {"corner", {-0.5, -0.5, 1}}, {"edge_u", {0, 1, 0}},
                                               {"edge_v", {1, 0, 0}}, {"material", "lamp"}}})}};
  json spec = point_spec(scene, {"light_area", "mis"}, 20000);
  const JobRun planned = run_spec(spec);
  spec["plan"] = "full";
  const JobRun full = run_spec(spec);
  EXPECT_FALSE(effect(planned, "shadow_rays")["on"].get<bool>());
  EXPECT_TRUE(effect(full, "shadow_rays")["on"].get<bool>());
  EXPECT_EQ(planned.counter(LightingCounter::shadow_rays), 0u);
  EXPECT_GT(full.counter(LightingCounter::shadow_rays), 0u);
  EXPECT_EQ(planned.counter(LightingCounter::sky_lookups), 0u);
  expect_same_answer(planned, full);
}

TEST(Planner, OccluderTurnsShadowRaysOn) {
  json spec = point_spec(lecture_scene(), {"light_area"}, 20000);
  const JobRun r = run_spec(spec);
  EXPECT_TRUE(effect(r, "shadow_rays")["on"].get<bool>());
  EXPECT_GT(r.counter(LightingCounter::shadow_rays), 0u);
}

TEST(Planner, BlackSurfacesNeedNoBounces) {
  // Light + black occluder; the receiver is the query point: nothing reflects.
  json scene = {{"materials", {{"lamp", emitter(3.0)}, {"black", diffuse(0.0)}}},
                {"shapes", json::array({
                               {{"type", "quad"}, {"corner", {-0.5, -0.5, 2}}, {"edge_u", {0, 1, 0}}, {"edge_v", {1, 0, 0}}, {"material", "lamp"}},
                               {{"type", "disk"}, {"center", {0.3, 0, 1}}, {"normal", {0, 0, 1}}, {"radius", 0.3}, {"material", "black"}},
                           })}};
  json spec = point_spec(scene, {"light_area", "mis"}, 20000);
  spec["query"]["max_depth"] = 4;
  const JobRun planned = run_spec(spec);
  spec["plan"] = "full";
  const JobRun full = run_spec(spec);
  EXPECT_FALSE(effect(planned, "indirect")["on"].get<bool>());
  EXPECT_LT(planned.counter(LightingCounter::bounce_rays), full.counter(LightingCounter::bounce_rays));
  expect_same_answer(planned, full);

  // light_area alone traces no BSDF rays at all when there is nothing to bounce off.
  json la = point_spec(scene, {"light_area"}, 5000);
  la["query"]["max_depth"] = 4;
  EXPECT_EQ(run_spec(la).counter(LightingCounter::bounce_rays), 0u);
}

TEST(Planner, NoSkyNoEmittersNoSpecular) {
  const json scene = {{"materials", {{"white", diffuse(0.5)}}},
                      {"shapes", json::array({{{"type", "quad"}, {"corner", {-1, -1, 1}}, {"edge_u", {2, 0, 0}},
                                               {"edge_v", {0, 2, 0}}, {"material", "white"}}})},
                      {"lights", json::array({{{"type", "point"}, {"position", {0.2, 0.1, 0.5}}, {"intensity", {1, 1, 1}}}})}};
  json spec = point_spec(scene, {"cosine_hemisphere", "mis"}, 5000);
  spec["query"]["max_depth"] = 3;
  const JobRun planned = run_spec(spec);
  spec["plan"] = "full";
  const JobRun full = run_spec(spec);
  EXPECT_FALSE(effect(planned, "sky")["on"].get<bool>());
  EXPECT_FALSE(effect(planned, "emission")["on"].get<bool>());
  EXPECT_FALSE(effect(planned, "specular")["on"].get<bool>());
  EXPECT_EQ(planned.counter(LightingCounter::sky_lookups), 0u);
  EXPECT_EQ(planned.counter(LightingCounter::emission_lookups), 0u);
  EXPECT_GT(full.counter(LightingCounter::sky_lookups), 0u);
  EXPECT_GT(full.counter(LightingCounter::emission_lookups), 0u);
  EXPECT_EQ(planned.counter(LightingCounter::specular_events), 0u);
  expect_same_answer(planned, full);
  // Point light at 0.5 above the point: direct part rho/pi * I / d^2 at least.
  EXPECT_GT(planned.channel(0).mean, 0.0);
}

TEST(Planner, ImageOfLectureSceneMatchesFull) {
  json scene = lecture_scene();
  scene["camera"] = {{"position", {0, -6, 4}}, {"look_at", {0, 0, 0.5}}, {"fov_deg", 40}, {"resolution", {24, 16}}};
  scene["materials"]["mirror"] = {{"type", "mirror"}};
  scene["shapes"].push_back({{"type", "sphere"}, {"center", {1.5, 1.0, 0.5}}, {"radius", 0.5}, {"material", "mirror"}});
  for (const std::string est : {"light_area", "mis", "cosine_hemisphere"}) {
    json spec = {{"kind", "lighting"}, {"seed", 11}, {"scene", scene},
                 {"query", {{"type", "image"}, {"max_depth", 3}, {"russian_roulette", true}}},
                 {"estimators", {est}}, {"stop", {{"max_samples", 32}}}};
    const JobRun planned = run_spec(spec, 2);
    spec["plan"] = "full";
    const JobRun full = run_spec(spec, 2);
    EXPECT_TRUE(effect(planned, "specular")["on"].get<bool>());
    EXPECT_GT(planned.counter(LightingCounter::specular_events), 0u);
    EXPECT_EQ(planned.counter(LightingCounter::sky_lookups), 0u);
    // Whole-image mean (pixels are independent).
    Tally a, b;
    for (size_t i = 0; i < planned.runner->state().channels.size(); i += 3) {
      a.merge(planned.channel(i));
      b.merge(full.channel(i));
    }
    EXPECT_LE(std::fabs(a.mean - b.mean), 4 * std::hypot(a.std_error(), b.std_error())) << est;
  }
}

TEST(Planner, NarrowGlossyLobesGetACaveatOnTheErrorBars) {
  // A polished metal wall beside the receiver: from max_depth 2 light can reach the
  // receiver through the wall's narrow lobe, found by BSDF sampling alone; the specular
  // line says so, with the count and the lowest roughness. Not at depth 1, not for a
  // rough metal; it is a caveat, so no effect switches (specular stays off, indirect on).
  auto spec_with = [](double roughness, int depth) {
    json scene = lecture_scene();
    scene["materials"]["polished silver"] = {{"type", "metallic_roughness"}, {"base_color", {0.97, 0.96, 0.91}},
                                             {"metallic", 1.0}, {"roughness", roughness}};
    scene["shapes"].push_back({{"type", "quad"}, {"corner", {-1, -1, 0}}, {"edge_u", {0, 2, 0}},
                               {"edge_v", {0, 0, 2}}, {"material", "polished silver"}});
    json spec = point_spec(scene, {"mis"}, 2000);
    spec["query"]["max_depth"] = depth;
    return spec;
  };
  const std::string caveat = "found by BSDF sampling alone";
  const JobRun narrow = run_spec(spec_with(0.08, 2));
  const std::string why = effect(narrow, "specular")["why"].get<std::string>();
  EXPECT_NE(why.find("glossy surfaces are sampled through their lobes"), std::string::npos) << why;
  EXPECT_NE(why.find(caveat), std::string::npos) << why;
  EXPECT_NE(why.find("glossy materials of roughness < 0.3 (1 material, the lowest 0.08)"), std::string::npos) << why;
  EXPECT_FALSE(effect(narrow, "specular")["on"].get<bool>());
  EXPECT_TRUE(effect(narrow, "indirect")["on"].get<bool>());

  const std::string direct = effect(run_spec(spec_with(0.08, 1)), "specular")["why"].get<std::string>();
  EXPECT_EQ(direct.find(caveat), std::string::npos) << direct;
  const std::string rough = effect(run_spec(spec_with(0.5, 3)), "specular")["why"].get<std::string>();
  EXPECT_EQ(rough.find(caveat), std::string::npos) << rough;
}

}  // namespace
}  // namespace tally::test
