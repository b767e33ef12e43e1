// Coverage of the 95% interval over many seeds, and chi-square tests of the light
// sampling routines' direction distributions against the pdf that MIS uses.
#include <gtest/gtest.h>


#include "common/lighting/accel.hpp"
#include "common/lighting/light_set.hpp"
#include "common/lighting/scene_json.hpp"
#include "common/lighting/localize_scene.hpp"
#include "common/rng/counter_rng.hpp"
#include "common/sampling/safe_math.hpp"
#include "lighting/lighting_test_support.hpp"
#include "support/chi_square.hpp"

namespace tally::test {
namespace {

TEST(Statistical, CoverageOfTheInterval) {
  const double R = 1.0, h = 1.0, L = 2.0, rho = 0.5;
  const json scene = {{"materials", {{"lamp", emitter(L)}}},
                      {"shapes", json::array({{{"type", "disk"}, {"center", {0, 0, h}}, {"normal", {0, 0, -1}},
                                               {"radius", R}, {"material", "lamp"}}})}};
  const double exact = rho * L * R * R / (R * R + h * h);
  const int seeds = 1000;
  int covered = 0;
  for (int s = 0; s < seeds; ++s) {
    const JobRun r = run_spec(point_spec(scene, {"uniform_hemisphere"}, 1000, rho, 1000 + static_cast<uint64_t>(s)));
    const Estimate e = r.runner->estimate(0);
    covered += e.ci_lo <= exact && exact <= e.ci_hi ? 1 : 0;
  }
  const double frac = static_cast<double>(covered) / seeds;
  EXPECT_GE(frac, 0.93);
  EXPECT_LE(frac, 0.97);
}

Scene local_scene(const json& j) {
  SpecReader r(j, "/scene");
  Scene s = parse_scene(r, JobLimits{});
  localize_scene(s);
  return s;
}

TEST(Statistical, ChiSquareQuadLightDirections) {
  // Directions from x sampled by the quad light, binned by where they cross the light
  // (cells in its (s, t) parameters); expected cell probability = ∫ pdf(w) dw over the
  // cell, with pdf(w) from LightSet::pdf_hit (what MIS uses), by 8x8 Gauss-free midpoint
  // sub-cells of a smooth integrand.
  const json j = {{"materials", {{"lamp", emitter(1.0)}}},
                  {"shapes", json::array({{{"type", "quad"}, {"corner", {-0.3, 0.2, 1.0}}, {"edge_u", {0.2, 0.9, -0.2}},
                                           {"edge_v", {1.2, 0.1, 0.3}}, {"material", "lamp"}}})}};
  const Scene scene = local_scene(j);
  const LightSet lights(scene);
  const Shape& q = scene.shapes[0];
  const Vec3 x = Vec3{0, 0, 0} - scene.origin, n{0, 0, 1};
  ASSERT_GT(dot(cross(q.edge_u, q.edge_v), x - q.corner), 0) << "light faces away";
  const int G = 16;
  const uint64_t N = 1000000;
  std::vector<double> obs(G * G, 0), expct(G * G, 0);
  const Vec3 qn = normalize(cross(q.edge_u, q.edge_v));
  for (uint64_t i = 0; i < N; ++i) {
    const SampleRng rng(99, i);
    const LightSample ls = lights.sample(x, n, rng.uniform(0), rng.uniform(1), rng.uniform(2));
    ASSERT_GT(ls.pdf, 0);
    // Where the direction crosses the light plane, in (s, t).
    const double t_hit = dot(q.corner - x, qn) / dot(ls.wi, qn);
    const Vec3 p = x + ls.wi * t_hit - q.corner;
    // Solve p = s eu + t ev (least squares, exact for in-plane p).
    const double a = dot(q.edge_u, q.edge_u), b = dot(q.edge_u, q.edge_v), c = dot(q.edge_v, q.edge_v);
    const double d = dot(p, q.edge_u), e = dot(p, q.edge_v), det = a * c - b * b;
    const double s = (c * d - b * e) / det, t = (a * e - b * d) / det;
    const int cs = std::clamp(static_cast<int>(s * G), 0, G - 1), ct = std::clamp(static_cast<int>(t * G), 0, G - 1);
    obs[static_cast<size_t>(ct * G + cs)] += 1;
  }
  const double area = length(cross(q.edge_u, q.edge_v));
  const int S = 8;
  double total = 0;
  for (int ct = 0; ct < G; ++ct) {
    for (int cs = 0; cs < G; ++cs) {
      double prob = 0;
      for (int k = 0; k < S * S; ++k) {
        const double s = (cs + (k % S + 0.5) / S) / G, t = (ct + (k / S + 0.5) / S) / G;
        Hit h;
        h.shape = 0;
        h.p = q.corner + q.edge_u * s + q.edge_v * t;
        h.n = qn;
        const Vec3 w = h.p - x;
        const double d2 = dot(w, w), cos_l = std::fabs(dot(qn, w)) / std::sqrt(d2);
        prob += lights.pdf_hit(x, h) * cos_l / d2 * area / (G * G * S * S);  // pdf dw = pdf cos/d^2 dA
      }
      expct[static_cast<size_t>(ct * G + cs)] = prob * static_cast<double>(N);
      total += prob;
    }
  }
  EXPECT_NEAR(total, 1.0, 1e-6);
  EXPECT_GT(chi_square_p(obs, expct), 0.01 / 3);  // Šidák over the 3 chi-square tests (+ light_choice_test)
}

TEST(Statistical, ChiSquareSphereConeDirections) {
  const json j = {{"materials", {{"lamp", emitter(1.0)}}},
                  {"shapes", json::array({{{"type", "sphere"}, {"center", {0.4, -0.3, 2.0}}, {"radius", 0.8}, {"material", "lamp"}}})}};
  const Scene scene = local_scene(j);
  const LightSet lights(scene);
  const Accel accel(scene);
  const Shape& sph = scene.shapes[0];
  const Vec3 x = Vec3{0, 0, 0} - scene.origin, n{0, 0, 1};
  const Vec3 axis = normalize(sph.center - x);
  const double cos_max = std::sqrt(1 - sph.radius * sph.radius / dot(sph.center - x, sph.center - x));
  const Frame f = Frame::from_normal(axis);
  const int GT = 20, GP = 40;
  const uint64_t N = 1000000;
  std::vector<double> obs(GT * GP, 0), expct(GT * GP, 0);
  for (uint64_t i = 0; i < N; ++i) {
    const SampleRng rng(7, i);
    const LightSample ls = lights.sample(x, n, rng.uniform(0), rng.uniform(1), rng.uniform(2));
    ASSERT_GT(ls.pdf, 0);
    ASSERT_NEAR(length(ls.p - sph.center), sph.radius, 1e-9);
    const Vec3 l = f.to_local(ls.wi);
    const double u = (1 - l.z) / (1 - cos_max);
    const double phi = std::atan2(l.y, l.x) + kPi;
    const int a = std::clamp(static_cast<int>(u * GT), 0, GT - 1), b = std::clamp(static_cast<int>(phi / (2 * kPi) * GP), 0, GP - 1);
    obs[static_cast<size_t>(a * GP + b)] += 1;
    if (i < 2000) {  // the pdf MIS uses agrees with the sampler's
      auto hit = accel.intersect(x, ls.wi, 1e30);
      ASSERT_TRUE(hit.has_value());
      EXPECT_NEAR(lights.pdf_hit(x, *hit), ls.pdf, 1e-9 * ls.pdf);
    }
  }
  // Cell solid angle = d(cos) d(phi); pdf is the constant cone density.
  const double pdf = lights.pdf_hit(x, Hit{0, sph.center - axis * sph.radius, -axis, 0, 0});
  for (int a = 0; a < GT; ++a) {
    for (int b = 0; b < GP; ++b) {
      expct[static_cast<size_t>(a * GP + b)] = pdf * (1 - cos_max) / GT * (2 * kPi / GP) * static_cast<double>(N);
    }
  }
  EXPECT_GT(chi_square_p(obs, expct), 0.01 / 3);
}

}  // namespace
}  // namespace tally::test
