// Lights are chosen in proportion to their power (alias table), and the pdfs MIS uses
// include that same choice probability: chi-square of the choices against the closed-form
// powers, and a many-light closed form through the production path.
#include <gtest/gtest.h>

#include <boost/math/distributions/chi_squared.hpp>
#include <fmt/format.h>

#include "common/lighting/light_set.hpp"
#include "common/lighting/scene_json.hpp"
#include "common/lighting/localize_scene.hpp"
#include "common/rng/counter_rng.hpp"
#include "common/sampling/safe_math.hpp"
#include "lighting/lighting_test_support.hpp"

namespace tally::test {
namespace {

const std::vector<std::string> kAll = {"uniform_hemisphere", "cosine_hemisphere", "light_area", "mis"};

json mesh_square(double x0, double y0, double side, double z, const std::string& material) {
  // Two triangles of unequal area (split off-centre through a fifth vertex) facing -z.
  const double x1 = x0 + side, y1 = y0 + side, xm = x0 + 0.3 * side;
  return {{"type", "mesh"},
          {"vertices", {x0, y0, z, x1, y0, z, x1, y1, z, x0, y1, z, xm, y1, z}},
          // areas side^2 * (0.5, 0.35, 0.15), all wound so that the normal is -z.
          {"indices", {0, 4, 1, 1, 4, 2, 0, 3, 4}},
          {"material", material}};
}

// The scene: a one-sided quad (L 2), a one-sided 3-triangle mesh (L 6, blue-ish), a
// sphere (L 40) and a two-sided disk (L 3), all above the receiver at the origin (normal
// +z) in separate directions, plus a sky (L 0.3) that they partly block.
json many_lights_scene() {
  return {{"materials", {{"q", emitter(2.0)},
                         {"m", {{"type", "emissive"}, {"radiance", {1.0, 4.0, 20.0}}}},
                         {"s", emitter(40.0)},
                         {"d", emitter(3.0, true)}}},
          {"shapes", json::array({{{"type", "quad"}, {"corner", {-1.2, -0.4, 1.5}}, {"edge_u", {0, 0.8, 0}}, {"edge_v", {0.6, 0, 0}}, {"material", "q"}},
                                  mesh_square(0.5, -0.5, 0.8, 2.0, "m"),
                                  {{"type", "sphere"}, {"center", {0, 1.2, 1.6}}, {"radius", 0.25}, {"material", "s"}},
                                  {{"type", "disk"}, {"center", {0.1, -1.6, 1.7}}, {"normal", {0, 0, 1}}, {"radius", 0.3}, {"material", "d"}}})},
          {"lights", json::array({{{"type", "sky"}, {"radiance", {0.3, 0.3, 0.3}}}})}};
}

double lum(double r, double g, double b) { return 0.2126 * r + 0.7152 * g + 0.0722 * b; }

TEST(LightChoice, ChiSquareOfChoicesAgainstPower) {
  const json j = many_lights_scene();
  SpecReader reader(j, "/scene");
  Scene scene = parse_scene(reader, JobLimits{});
  localize_scene(scene);
  const LightSet lights(scene);
  ASSERT_EQ(lights.sampled_count(), 5u);
  // Closed-form powers: pi A L (x2 two-sided); sky 4 pi^2 r^2 L, r = half the diagonal
  // of the shapes' bounds: x [-1.2, 1.3], y [-1.9, 1.45], z [1.35, 2.0].
  const double r = 0.5 * std::sqrt(2.5 * 2.5 + 3.35 * 3.35 + 0.65 * 0.65);
  const double a_tri[3] = {0.5 * 0.8 * 0.8, 0.5 * 0.8 * 0.8 * 0.7, 0.5 * 0.8 * 0.8 * 0.3};
  const double l_mesh = lum(1, 4, 20);
  const std::vector<double> power = {kPi * 0.48 * 2.0,
                                     kPi * a_tri[0] * l_mesh, kPi * a_tri[1] * l_mesh, kPi * a_tri[2] * l_mesh,
                                     kPi * 4 * kPi * 0.0625 * 40.0,
                                     kPi * kPi * 0.09 * 3.0 * 2,
                                     4 * kPi * kPi * r * r * 0.3};
  double total = 0;
  for (double p : power) total += p;
  // pick_pmf (what the pdfs use) = the closed form.
  EXPECT_NEAR(lights.pick_pmf(0), power[0] / total, 1e-5 * power[0] / total);  // float-rounded geometry
  EXPECT_NEAR(lights.pick_pmf(1), (power[1] + power[2] + power[3]) / total, 1e-5 * power[1] / total);
  EXPECT_NEAR(lights.pick_pmf(2), power[4] / total, 1e-5 * power[4] / total);
  EXPECT_NEAR(lights.pick_pmf(3), power[5] / total, 1e-5 * power[5] / total);
  EXPECT_NEAR(lights.pick_pmf_sky(), power[6] / total, 1e-5 * power[6] / total);
  EXPECT_NEAR(lights.pick_pmf(0) + lights.pick_pmf(1) + lights.pick_pmf(2) + lights.pick_pmf(3) + lights.pick_pmf_sky(), 1.0, 1e-12);

  // Which entry (light, mesh triangle) the sampler picks: 10^6 samples, 7 cells.
  const Vec3 x = Vec3{0, 0, 0} - scene.origin, n{0, 0, 1};
  const Shape& mesh = scene.shapes[1];
  const uint64_t N = 1000000;
  std::vector<double> obs(7, 0), expct(7, 0);
  for (uint64_t i = 0; i < N; ++i) {
    const SampleRng rng(21, i);
    const LightSample ls = lights.sample(x, n, rng.uniform(0), rng.uniform(1), rng.uniform(2));
    size_t cell = 6;
    if (!ls.sky) {
      const Vec3 p = ls.p + scene.origin;  // world coordinates
      if (p.x < -0.5) {
        cell = 0;
      } else if (p.y < -1.0) {
        cell = 5;
      } else if (p.y > 0.6) {
        cell = 4;
      } else {
        // Which triangle of the mesh: barycentric inside test in the plane z = 2.
        cell = 3;
        for (size_t t = 0; t < 3; ++t) {
          const auto& tri = mesh.triangles[t];
          const Vec3 a = mesh.vertices[tri[0]], b = mesh.vertices[tri[1]], c = mesh.vertices[tri[2]];
          const Vec3 q = ls.p;
          const double s0 = cross(b - a, q - a).z, s1 = cross(c - b, q - b).z, s2 = cross(a - c, q - c).z;
          if ((s0 <= 0 && s1 <= 0 && s2 <= 0) || (s0 >= 0 && s1 >= 0 && s2 >= 0)) {
            cell = 1 + t;
            break;
          }
        }
      }
    }
    obs[cell] += 1;
  }
  // The mesh's triangles in the order of the spec: areas a_tri[0..2] as listed above.
  for (size_t c = 0; c < 7; ++c) expct[c] = power[c] / total * static_cast<double>(N);
  double chi2 = 0;
  for (size_t c = 0; c < 7; ++c) chi2 += (obs[c] - expct[c]) * (obs[c] - expct[c]) / expct[c];
  const double p = boost::math::cdf(boost::math::complement(boost::math::chi_squared(6), chi2));
  for (size_t c = 0; c < 7; ++c) std::printf("  cell %zu: observed %.0f expected %.1f\n", c, obs[c], expct[c]);
  std::printf("  chi2 %.2f (6 dof), p %.3f\n", chi2, p);
  EXPECT_GT(p, 0.01 / 3);  // Šidák (Bonferroni bound) over this and the 2 in statistical_test
}

// Closed form with five lights of very different power: MIS's light pdf must carry the
// same (power-weighted) choice probability as the light sampler, or it is biased here.
TEST(LightChoice, ManyLightsClosedFormAllEstimators) {
  const double rho = 0.5;
  const JobRun r = run_spec(point_spec(many_lights_scene(), kAll, 200000, rho, 31));
  // Projected solid angles (cos-weighted) P of each shape from the origin, normal +z.
  const std::vector<Vec3> quad = {{-1.2, -0.4, 1.5}, {-1.2, 0.4, 1.5}, {-0.6, 0.4, 1.5}, {-0.6, -0.4, 1.5}};
  const std::vector<Vec3> square = {{0.5, -0.5, 2}, {1.3, -0.5, 2}, {1.3, 0.3, 2}, {0.5, 0.3, 2}};
  const double p_quad = lambert_irradiance(quad, {}, {0, 0, 1}, 1.0);
  const double p_mesh = lambert_irradiance(square, {}, {0, 0, 1}, 1.0);
  const double d_s = 2.0;  // |(0, 1.2, 1.6)|: sphere fully above the horizon: P = pi (R/d)^2 cos
  const double p_sphere = kPi * (0.25 / d_s) * (0.25 / d_s) * (1.6 / d_s);
  // Horizontal disk at height h, centre d off the receiver's axis (configuration factor
  // of a parallel disk; checked against 2-D quadrature to 1e-8):
  // P = pi/2 (1 - (h^2 + d^2 - R^2) / sqrt((h^2 + d^2 + R^2)^2 - 4 d^2 R^2)).
  const double h = 1.7, dd = std::hypot(0.1, -1.6), R = 0.3;
  const double p_disk = kPi / 2 * (1 - (h * h + dd * dd - R * R) / std::sqrt((h * h + dd * dd + R * R) * (h * h + dd * dd + R * R) - 4 * dd * dd * R * R));
  const double l_mesh[3] = {1.0, 4.0, 20.0};
  for (size_t c = 0; c < 3; ++c) {
    const double e = 2.0 * p_quad + l_mesh[c] * p_mesh + 40.0 * p_sphere + 3.0 * p_disk +
                     0.3 * (kPi - p_quad - p_mesh - p_sphere - p_disk);
    const double exact = rho / kPi * e;
    for (size_t est = 0; est < kAll.size(); ++est) {
      const Tally& t = r.channel(est * 3 + c);
      const double se = t.std_error();
      std::printf("  %-20s ch %zu mean %.6f exact %.6f se %.2e z %+.2f\n", kAll[est].c_str(), c, t.mean, exact, se,
                  (t.mean - exact) / se);
      EXPECT_LE(std::fabs(t.mean - exact), 4 * se) << kAll[est] << " channel " << c;
    }
  }
  EXPECT_EQ(r.counter(LightingCounter::nonfinite), 0u);
}

}  // namespace
}  // namespace tally::test
