// Point and spot lights in a light tree (common/lighting/delta_light_tree.hpp, issue 29):
// the pmf over all point/spot lights sums to 1 and is what sample() reports, bit for bit;
// every light that can light a point has pmf > 0 there; through the job, the one-light
// estimator equals the exact sum over all lights (closed form) within 4 se; images are
// bit-identical on 1 and 2 threads; the planner keeps the exact loop at or below
// kDeltaLightTreeMinLights point/spot lights and says which it chose.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "bench/many_lights_scene.hpp"
#include "common/lighting/delta_light_tree.hpp"
#include "common/rng/counter_rng.hpp"
#include "lighting/lighting_test_support.hpp"

namespace tally {
namespace {

using json = nlohmann::json;

constexpr double kDeg = kPi / 180.0;

// n lights at random positions in [-5, 5] x [0.5, 3] x [-5, 5] with random RGB
// intensities; every fifth a spot (random axis in the lower hemisphere, outer 20..80
// degrees, inner 0..outer), every 37th a directional light. As JSON (what the job reads)
// and as the DeltaLight the reader makes of it (the closed form uses the same cosines).
struct RandomLights {
  json lights = json::array();
  std::vector<DeltaLight> parsed;
};
RandomLights random_lights(int n, uint64_t seed) {
  RandomLights r;
  for (int k = 0; k < n; ++k) {
    const SampleRng rng(seed, static_cast<uint64_t>(k));
    const Vec3 p{10 * rng.uniform(0) - 5, 0.5 + 2.5 * rng.uniform(1), 10 * rng.uniform(2) - 5};
    const Rgb I{0.1 + rng.uniform(3), 0.1 + rng.uniform(4), 0.1 + rng.uniform(5)};
    DeltaLight d;
    d.position = p;
    d.intensity = I;
    json l = {{"position", test::vec(p)}, {"intensity", {I.x, I.y, I.z}}};
    if (k % 37 == 36) {
      d.type = DeltaLightType::directional;
      d.direction = normalize(Vec3{rng.uniform(6) - 0.5, 1.0, rng.uniform(7) - 0.5});
      d.intensity = I * 0.2;
      l = {{"type", "directional"}, {"direction", test::vec(d.direction)}, {"irradiance", {0.2 * I.x, 0.2 * I.y, 0.2 * I.z}}};
    } else if (k % 5 == 4) {
      d.type = DeltaLightType::spot;
      const double cz = 0.3 + 0.7 * rng.uniform(6), phi = 2 * kPi * rng.uniform(7), sz = std::sqrt(1 - cz * cz);
      d.direction = normalize(Vec3{sz * std::cos(phi), -cz, sz * std::sin(phi)});
      const double outer = 20 + 60 * rng.uniform(8), inner = outer * rng.uniform(9);
      d.cos_inner = std::cos(inner * kDeg);
      d.cos_outer = std::cos(outer * kDeg);
      l["type"] = "spot";
      l["direction"] = test::vec(d.direction);
      l["outer_cone_deg"] = outer;
      l["inner_cone_deg"] = inner;
    } else {
      l["type"] = "point";
    }
    r.lights.push_back(l);
    r.parsed.push_back(d);
  }
  return r;
}

Scene scene_of(const std::vector<DeltaLight>& lights) {
  Scene s;
  s.delta_lights = lights;
  return s;
}

// Shading points around and among the lights.
Vec3 random_point(uint64_t seed, uint64_t i) { return test::random_point(seed, i, {-6, -0.5, -6}, {6, 3.5, 6}); }

TEST(DeltaLightTree, PmfSumsToOneAndSampleReportsItExactly) {
  const RandomLights L = random_lights(300, 3);
  const Scene scene = scene_of(L.parsed);
  const DeltaLightTree tree(scene);
  ASSERT_EQ(tree.leaves(), positioned_light_count(scene));
  ASSERT_EQ(tree.leaves() + tree.directional().size(), L.parsed.size());
  ASSERT_GT(tree.directional().size(), 0u);
  for (uint64_t k = 0; k < 40; ++k) {
    const Vec3 p = random_point(17, k);
    double sum = 0;
    for (uint32_t i = 0; i < L.parsed.size(); ++i) {
      const double pmf = tree.pmf(p, i);
      if (L.parsed[i].type == DeltaLightType::directional) {
        EXPECT_EQ(pmf, 0.0);
      }
      sum += pmf;
    }
    EXPECT_NEAR(sum, 1.0, 1e-12) << "point " << k;
    for (uint64_t j = 0; j < 300; ++j) {
      const auto pk = tree.sample(p, SampleRng(k, j).uniform(0));
      ASSERT_TRUE(pk.has_value());
      EXPECT_EQ(pk->pmf, tree.pmf(p, pk->light));  // bit for bit
      EXPECT_NE(L.parsed[pk->light].type, DeltaLightType::directional);
    }
  }
}

TEST(DeltaLightTree, ALightThatReachesThePointIsNeverGivenProbabilityZero) {
  // Point lights light every point; a spot light lights p where its falloff is > 0
  // (inside the outer cone). Such a light with pmf 0 would bias the estimator.
  const RandomLights L = random_lights(300, 5);
  const DeltaLightTree tree(scene_of(L.parsed));
  size_t spots_checked = 0, spots_dark = 0;
  for (uint64_t k = 0; k < 60; ++k) {
    const Vec3 p = random_point(29, k);
    for (uint32_t i = 0; i < L.parsed.size(); ++i) {
      const DeltaLight& d = L.parsed[i];
      if (d.type == DeltaLightType::directional) continue;
      const bool lit = d.type == DeltaLightType::point || spot_falloff(d, normalize(p - d.position)) > 0;
      if (lit) {
        EXPECT_GT(tree.pmf(p, i), 0.0) << "light " << i << " point " << k;
      }
      if (d.type == DeltaLightType::spot) {
        spots_checked += lit ? 1 : 0;
        spots_dark += lit ? 0 : 1;
      }
    }
  }
  // Both cases occur (the spots' cones are narrow enough to leave points dark).
  EXPECT_GT(spots_checked, 500u);
  EXPECT_GT(spots_dark, 500u);
}

// Radiance off a diffuse plane y = 0 (albedo a, normal +y) at p: the exact sum over all
// lights, (a / pi) sum I falloff cos / d^2 (+ E cos for directional lights); every light
// is above the plane and nothing else is in the scene, so every light is visible.
Rgb exact_radiance(const std::vector<DeltaLight>& lights, const Vec3& p, double a) {
  const Vec3 n{0, 1, 0};
  Rgb sum{};
  for (const DeltaLight& d : lights) {
    if (d.type == DeltaLightType::directional) {
      sum += d.intensity * std::max(0.0, dot(n, d.direction));
      continue;
    }
    const Vec3 to = d.position - p;
    const double d2 = dot(to, to);
    const Vec3 wi = to / std::sqrt(d2);
    double f = 1.0;
    if (d.type == DeltaLightType::spot) f = spot_falloff(d, -wi);
    sum += d.intensity * (f * std::max(0.0, dot(n, wi)) / d2);
  }
  return sum * (a / kPi);
}

json plane_spec(const json& lights, const std::vector<Vec3>& points, const std::string& selection, uint64_t samples) {
  json pts = json::array();
  for (const Vec3& p : points) pts.push_back({{"p", test::vec(p)}, {"n", {0, 1, 0}}, {"material", test::diffuse(0.5)}});
  const json scene = {{"shapes", json::array({{{"type", "quad"}, {"corner", {-8, 0, -8}}, {"edge_u", {0, 0, 16}},
                                                {"edge_v", {16, 0, 0}}, {"material", test::diffuse(0.5)}}})},
                      {"lights", lights}};
  return {{"kind", "lighting"}, {"seed", 5}, {"sampler", "independent"}, {"light_selection", selection},
          {"scene", scene}, {"query", {{"type", "points"}, {"max_depth", 1}, {"points", pts}}},
          {"estimators", {"mis"}}, {"stop", {{"max_samples", samples}}}};
}


TEST(DeltaLightTree, OneLightEstimateEqualsTheExactSumOverAllLights) {
  // 240 lights (187 point, 47 spot, 6 directional) over a diffuse
  // plane, three receivers on it, 40,000 independent samples each, the planner's choice
  // ("auto": more than 64 point/spot lights, so the tree). Each channel's mean is within
  // 4 se of the closed form: 9 channels, false-failure rate under normality at most
  // 9 x 6.3e-5 = 5.7e-4 (fixed seed: it passes or fails deterministically).
  const RandomLights L = random_lights(240, 7);
  const std::vector<Vec3> points{{0.2, 0, -0.3}, {-4.5, 0, 3.5}, {5.5, 0, 5.5}};
  const uint64_t n = 40000;
  const test::JobRun r = test::run_spec(plane_spec(L.lights, points, "auto", n));
  const json e = test::plan_effect(r, "delta_light_tree");
  ASSERT_FALSE(e.is_null());
  ASSERT_TRUE(e["on"].get<bool>()) << e.dump();
  // One shadow ray per sample for the picked light plus one per directional light
  // (the plane would not block them, but the planner cannot know that).
  size_t directional = 0, spots = 0;
  for (const DeltaLight& d : L.parsed) {
    directional += d.type == DeltaLightType::directional ? 1 : 0;
    spots += d.type == DeltaLightType::spot ? 1 : 0;
  }
  ASSERT_EQ(directional, 6u);
  ASSERT_EQ(spots, 47u);
  EXPECT_LE(r.counter(LightingCounter::shadow_rays), points.size() * n * (1 + directional));
  EXPECT_GT(r.counter(LightingCounter::shadow_rays), points.size() * n * directional);
  for (size_t k = 0; k < points.size(); ++k) {
    const Rgb exact = exact_radiance(L.parsed, points[k], 0.5);
    const double ex[3] = {exact.x, exact.y, exact.z};
    for (size_t c = 0; c < 3; ++c) {
      const Tally& t = r.channel(3 * k + c);
      const double se = std::sqrt(t.variance() / static_cast<double>(t.n));
      ASSERT_EQ(t.n, n);
      EXPECT_GT(se, 0.0);  // a real estimate, not the loop's exact sum
      EXPECT_NEAR(t.mean, ex[c], 4 * se) << "point " << k << " channel " << c;
      if (c == 1) std::printf("point %zu: tree %.6f +- %.6f, exact %.6f\n", k, t.mean, se, ex[c]);
    }
  }
}

TEST(DeltaLightTree, ImagesAreBitIdenticalOnOneAndTwoThreads) {
  const json spec = test::room_image_spec(scenes::many_point_lights_scene(300));
  const test::JobRun one = test::run_spec(spec, 1);
  const test::JobRun two = test::run_spec(spec, 2);
  ASSERT_TRUE(test::plan_effect(one, "delta_light_tree")["on"].get<bool>());
  EXPECT_EQ(test::differing_channels(one, two), 0u);
  EXPECT_GT(test::state_total(one), 0.0);
}

TEST(DeltaLightTree, PlannerKeepsTheExactLoopAtOrBelowTheThreshold) {
  // kDeltaLightTreeMinLights point lights (all above one receiver): the plan says
  // "loop", and the job traces one shadow ray per light per sample and has no
  // selection noise (variance 0 at max_depth 1); one more light and the tree is on:
  // one shadow ray per sample.
  auto points_only = [](size_t n) {
    json lights = json::array();
    for (size_t k = 0; k < n; ++k) {
      const SampleRng rng(11, k);
      lights.push_back({{"type", "point"}, {"position", {8 * rng.uniform(0) - 4, 1 + rng.uniform(1), 8 * rng.uniform(2) - 4}},
                        {"intensity", {1, 1, 1}}});
    }
    return lights;
  };
  const std::vector<Vec3> at{{0, 0, 0}};
  const uint64_t n = 64;
  const size_t few = kDeltaLightTreeMinLights, many = kDeltaLightTreeMinLights + 1;

  const test::JobRun loop = test::run_spec(plane_spec(points_only(few), at, "auto", n));
  const json off = test::plan_effect(loop, "delta_light_tree");
  ASSERT_FALSE(off.is_null());
  EXPECT_FALSE(off["on"].get<bool>());
  EXPECT_NE(off["why"].get<std::string>().find("64 point/spot lights, at most 64"), std::string::npos) << off.dump();
  EXPECT_EQ(loop.counter(LightingCounter::shadow_rays), few * n);
  EXPECT_EQ(loop.channel(0).variance(), 0.0);

  const test::JobRun tree = test::run_spec(plane_spec(points_only(many), at, "auto", n));
  const json on = test::plan_effect(tree, "delta_light_tree");
  ASSERT_FALSE(on.is_null());
  EXPECT_TRUE(on["on"].get<bool>());
  EXPECT_NE(on["why"].get<std::string>().find("65 point/spot lights, more than 64"), std::string::npos) << on.dump();
  EXPECT_EQ(tree.counter(LightingCounter::shadow_rays), n);
  EXPECT_GT(tree.channel(0).variance(), 0.0);

  // "light_selection" forces either way; "plan": "full" does not force the tree.
  EXPECT_FALSE(test::plan_effect(test::run_spec(plane_spec(points_only(many), at, "power", 2)), "delta_light_tree")["on"].get<bool>());
  EXPECT_TRUE(test::plan_effect(test::run_spec(plane_spec(points_only(3), at, "tree", 2)), "delta_light_tree")["on"].get<bool>());
  json full = plane_spec(points_only(few), at, "auto", 2);
  full["plan"] = "full";
  EXPECT_FALSE(test::plan_effect(test::run_spec(full), "delta_light_tree")["on"].get<bool>());
  // Without point or spot lights the plan has no such line.
  const json dir = json::array({{{"type", "directional"}, {"direction", {0, 1, 0}}, {"irradiance", {1, 1, 1}}}});
  EXPECT_TRUE(test::plan_effect(test::run_spec(plane_spec(dir, at, "auto", 2)), "delta_light_tree").is_null());
}

}  // namespace
}  // namespace tally
