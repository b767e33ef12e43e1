// The light hierarchy (common/lighting/light_tree.hpp) and its use by the light set:
// the pmf over all lights sums to 1 at any point that some light can reach; sample()
// reports exactly pmf(); selection frequencies match pmf (chi-square, Šidák); a light
// that faces the point is never given probability 0 (no bias); the build is
// deterministic. Through the whole job: on a room with 1,200 small emitters the tree's
// estimate equals power selection's within 4 se, images are bit-identical on 1 and 2
// threads, and the planner switches the tree on above kLightTreeMinEmitters only.
// The room is bench/many_lights_scene.hpp's (the bench renders the same scene).
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <vector>

#include "bench/many_lights_scene.hpp"
#include "common/lighting/accel.hpp"
#include "common/lighting/light_set.hpp"
#include "common/lighting/light_tree.hpp"
#include "common/lighting/localize_scene.hpp"
#include "common/rng/counter_rng.hpp"
#include "lighting/lighting_test_support.hpp"
#include "support/chi_square.hpp"

namespace tally {
namespace {

using json = nlohmann::json;

// Random small one-sided triangles (and some two-sided, some spheres) in [-5, 5]^3.
struct RandomLights {
  std::vector<LightBounds> leaves;
  std::vector<Vec3> centroid;
};
RandomLights random_lights(size_t n, uint64_t seed) {
  RandomLights r;
  for (size_t i = 0; i < n; ++i) {
    const SampleRng rng(seed, i);
    const Vec3 c{10 * rng.uniform(0) - 5, 10 * rng.uniform(1) - 5, 10 * rng.uniform(2) - 5};
    const double z = 2 * rng.uniform(3) - 1, phi = 2 * kPi * rng.uniform(4), s = std::sqrt(1 - z * z);
    LightBounds b;
    const double h = 0.05 + 0.2 * rng.uniform(5);
    b.lo = c - Vec3{h, h, h};
    b.hi = c + Vec3{h, h, h};
    b.w = {s * std::cos(phi), s * std::sin(phi), z};
    b.phi = 0.1 + 10 * rng.uniform(6);
    b.two_sided = i % 7 == 0;
    if (i % 11 == 0) b.cos_o = -1.0;  // a sphere
    r.leaves.push_back(b);
    r.centroid.push_back(c);
  }
  return r;
}

Vec3 random_point(uint64_t seed, uint64_t i) { return test::random_point(seed, i, {-6, -6, -6}, {6, 6, 6}); }

TEST(LightTree, PmfSumsToOneAndSampleReportsItExactly) {
  const RandomLights L = random_lights(500, 3);
  const LightTree tree(L.leaves);
  EXPECT_EQ(tree.node_count(), 2 * L.leaves.size() - 1);
  for (uint64_t k = 0; k < 40; ++k) {
    const Vec3 p = random_point(17, k);
    double sum = 0;
    for (uint32_t i = 0; i < L.leaves.size(); ++i) sum += tree.pmf(p, i);
    EXPECT_NEAR(sum, 1.0, 1e-12) << "point " << k;
    for (uint64_t j = 0; j < 200; ++j) {
      const SampleRng rng(k, j);
      const auto pk = tree.sample(p, rng.uniform(0));
      ASSERT_TRUE(pk.has_value());
      EXPECT_EQ(pk->pmf, tree.pmf(p, pk->leaf));  // bit for bit: what MIS uses
      EXPECT_GT(pk->pmf, 0.0);
    }
  }
}

TEST(LightTree, ALightFacingThePointIsNeverGivenProbabilityZero) {
  // One-sided leaves: a light whose normal side holds p (dot(w, p - c) > 0 by a margin)
  // can light p, so its pmf must be > 0 (otherwise the estimator would be biased).
  const RandomLights L = random_lights(500, 5);
  const LightTree tree(L.leaves);
  size_t checked = 0;
  for (uint64_t k = 0; k < 40; ++k) {
    const Vec3 p = random_point(23, k);
    for (uint32_t i = 0; i < L.leaves.size(); ++i) {
      const Vec3 d = p - L.centroid[i];
      if (L.leaves[i].cos_o == -1.0 || L.leaves[i].two_sided || dot(L.leaves[i].w, d) > 1e-6 * length(d)) {
        EXPECT_GT(tree.pmf(p, i), 0.0) << "leaf " << i << " point " << k;
        ++checked;
      }
    }
  }
  EXPECT_GT(checked, 10000u);
}

TEST(LightTree, SelectionFrequenciesMatchThePmf) {
  // 200 leaves, 4 points, 400,000 samples each; chi-square of the leaf counts against
  // N pmf (cells under 5 expected pooled). Šidák: each point at 1 - 0.99^(1/4), the
  // test's false-failure rate is 1% (fixed seeds: it passes or fails deterministically).
  const RandomLights L = random_lights(200, 9);
  const LightTree tree(L.leaves);
  const int points = 4;
  const double alpha_each = test::sidak_level(0.01, points);
  const uint64_t N = 400000;
  for (int k = 0; k < points; ++k) {
    const Vec3 p = random_point(31, static_cast<uint64_t>(k));
    std::vector<double> obs(L.leaves.size(), 0), expct(L.leaves.size(), 0);
    for (uint64_t j = 0; j < N; ++j) {
      const SampleRng rng(1000 + static_cast<uint64_t>(k), j);
      const auto pk = tree.sample(p, rng.uniform(0));
      ASSERT_TRUE(pk.has_value());
      obs[pk->leaf] += 1;
    }
    for (uint32_t i = 0; i < L.leaves.size(); ++i) expct[i] = static_cast<double>(N) * tree.pmf(p, i);
    EXPECT_GT(test::chi_square_p(obs, expct), alpha_each) << "point " << k;
  }
}

TEST(LightTree, BuildIsDeterministicAndSkipsPowerlessLeaves) {
  RandomLights L = random_lights(300, 11);
  L.leaves[7].phi = 0;
  const LightTree a(L.leaves), b(L.leaves);
  const Vec3 p{0.5, -0.25, 1};
  EXPECT_EQ(a.pmf(p, 7), 0.0);
  for (uint64_t j = 0; j < 2000; ++j) {
    const double u = SampleRng(4, j).uniform(0);
    const auto x = a.sample(p, u), y = b.sample(p, u);
    ASSERT_TRUE(x && y);
    EXPECT_EQ(x->leaf, y->leaf);
    EXPECT_EQ(x->pmf, y->pmf);
    EXPECT_NE(x->leaf, 7u);
  }
}

// --- through the job --------------------------------------------------------------------

json many_light_scene(int n) { return scenes::many_lights_scene(n); }

TEST(LightTree, LightSetPdfOfASampledPointIsWhatMisEvaluatesForItsHit) {
  // The light set with the tree: a light sample's pdf (choice x point density) equals
  // pdf_hit at the point the ray towards it hits (what MIS evaluates for a BSDF ray
  // that finds that emitter), and the choice probabilities of all emitters and the sky
  // sum to 1. Points in the room, 300 emitters plus a sky (so the sky's share is used).
  json sj = many_light_scene(300);
  sj["lights"] = json::array({{{"type", "sky"}, {"radiance", {0.5, 0.5, 0.5}}}});
  Scene scene = test::parse_scene_json(sj, {});
  localize_scene(scene);
  const Accel accel(scene);
  const LightSet lights(scene, LightSelection::tree);
  ASSERT_EQ(lights.selection(), LightSelection::tree);
  ASSERT_EQ(lights.emitter_entries(), 300u);
  size_t checked = 0;
  for (uint64_t k = 0; k < 20; ++k) {
    const SampleRng prng(41, k);
    const Vec3 x = Vec3{-5.5 + 11 * prng.uniform(0), 0.1 + 2.5 * prng.uniform(1), -5.5 + 11 * prng.uniform(2)} - scene.origin;
    const Vec3 n{0, 1, 0};
    double sum = lights.pick_pmf_sky();
    for (uint32_t sh = 0; sh < scene.shapes.size(); ++sh) sum += lights.choice_pmf(x, sh, 0);
    EXPECT_NEAR(sum, 1.0, 1e-12) << "point " << k;
    for (uint64_t j = 0; j < 200; ++j) {
      const SampleRng rng(43 + k, j);
      const LightSample ls = lights.sample(x, n, rng.uniform(0), rng.uniform(1), rng.uniform(2));
      if (!(ls.pdf > 0) || ls.sky) continue;
      const std::optional<Hit> hit = accel.intersect(x, ls.wi, 1e30);
      if (!hit || !lights.is_light(hit->shape) || std::fabs(hit->t - ls.dist) > 1e-4 * ls.dist) continue;  // occluded
      // 1e-2: Embree's float hit point moves d^2 / cos by up to ~1e-3 at grazing angles;
      // a wrong choice probability (e.g. power selection's) is off by factors.
      EXPECT_NEAR(lights.pdf_hit(x, *hit), ls.pdf, 1e-2 * ls.pdf) << "point " << k << " sample " << j;
      EXPECT_NEAR(lights.pdf_dir(x, ls.wi, *hit), ls.pdf, 1e-2 * ls.pdf);
      ++checked;
    }
  }
  EXPECT_GT(checked, 300u);
}

json point_spec(const json& scene, const std::string& selection, uint64_t samples) {
  return {{"kind", "lighting"}, {"seed", 21}, {"light_selection", selection}, {"scene", scene},
          {"query", {{"type", "points"}, {"max_depth", 1},
                     {"points", json::array({{{"p", {-4.5, 0.0, 4.0}}, {"n", {0, 1, 0}}, {"material", test::diffuse(0.5)}},
                                             {{"p", {0.3, 1.2, -6.0}}, {"n", {0, 0, 1}}, {"material", test::diffuse(0.5)}}})}}},
          {"estimators", {"mis"}}, {"stop", {{"max_samples", samples}}}};
}

TEST(LightTree, ManyLightEstimateEqualsPowerSelectionWithinErrorBars) {
  // bench/many_lights_scene.hpp with 1,200 emitters; two receivers (floor, back wall). Independent samples; the
  // tree's and power selection's estimates agree within 4 se of their difference (2
  // points x 3 channels, false-failure rate ~4e-4 under normality). The se ratio is
  // printed (0.277 and 0.312 with these seeds: the tree needs 10-13x fewer samples here)
  // and asserted < 0.8 (the se estimates at 20,000 samples are good to a few percent).
  const json scene = many_light_scene(1200);
  const test::JobRun tree = test::run_spec(point_spec(scene, "tree", 20000));
  const test::JobRun power = test::run_spec(point_spec(scene, "power", 20000));
  for (size_t c = 0; c < 6; ++c) {
    const Tally& a = tree.channel(c);
    const Tally& b = power.channel(c);
    const double sa = std::sqrt(a.variance() / static_cast<double>(a.n)), sb = std::sqrt(b.variance() / static_cast<double>(b.n));
    ASSERT_GT(b.mean, 0.0);
    EXPECT_NEAR(a.mean, b.mean, 4.0 * std::hypot(sa, sb)) << "channel " << c;
    EXPECT_LT(sa, 0.8 * sb) << "channel " << c;
    if (c % 3 == 1) std::printf("point %zu: tree %.5f +- %.5f, power %.5f +- %.5f, se ratio tree/power %.3f\n", c / 3, a.mean, sa,
                                b.mean, sb, sa / sb);
  }
  // The tree is what the plan says.
  bool seen = false;
  const json plan = plan_json(*tree.job);
  for (const json& e : plan["plan"]["effects"]) {
    if (e["effect"] == "light_tree") seen = e["on"].get<bool>();
  }
  EXPECT_TRUE(seen) << plan.dump();
}

TEST(LightTree, ImagesAreBitIdenticalOnOneAndTwoThreads) {
  const json spec = test::room_image_spec(many_light_scene(300));
  const test::JobRun one = test::run_spec(spec, 1);
  const test::JobRun two = test::run_spec(spec, 2);
  EXPECT_EQ(test::differing_channels(one, two), 0u);
  EXPECT_GT(test::state_total(one), 0.0);
}

TEST(LightTree, PlannerUsesTheTreeAboveTheThresholdOnly) {
  auto effect = [](const test::JobRun& r) { return test::plan_effect(r, "light_tree"); };
  const json few = many_light_scene(static_cast<int>(kLightTreeMinEmitters));
  const json many = many_light_scene(static_cast<int>(kLightTreeMinEmitters) + 1);
  EXPECT_TRUE(effect(test::run_spec(point_spec(few, "auto", 2))).is_null());
  const json on = effect(test::run_spec(point_spec(many, "auto", 2)));
  ASSERT_FALSE(on.is_null());
  EXPECT_TRUE(on["on"].get<bool>());
  EXPECT_NE(on["why"].get<std::string>().find("65 emitter entries"), std::string::npos) << on.dump();
  EXPECT_FALSE(effect(test::run_spec(point_spec(many, "power", 2)))["on"].get<bool>());
  EXPECT_TRUE(effect(test::run_spec(point_spec(few, "tree", 2)))["on"].get<bool>());
  // "plan": "full" does not force it (both selections are exact).
  json full = point_spec(few, "auto", 2);
  full["plan"] = "full";
  EXPECT_TRUE(effect(test::run_spec(full)).is_null());
  // Bad input names the field.
  try {
    compile_lighting_job(point_spec(few, "bvh", 2), {});
    ADD_FAILURE() << "accepted light_selection \"bvh\"";
  } catch (const SpecError& e) {
    EXPECT_EQ(std::string(e.what()).rfind("/light_selection", 0), 0u) << e.what();
  }
}

}  // namespace
}  // namespace tally
