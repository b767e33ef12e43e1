// The GGX materials through the production path (JSON -> job -> path tracer): under a
// point light the answer is deterministic and equals the BSDF written out here
// independently; under an area light every estimator (and MIS with the glossy pdf)
// agrees; a mesh's shading normals are used.
#include <gtest/gtest.h>

#include <cmath>

#include <filesystem>
#include <fstream>

#include "common/sampling/safe_math.hpp"
#include "lighting/gltf/gltf_writer.hpp"
#include "lighting/lighting_test_support.hpp"

namespace tally {
namespace {

using json = nlohmann::json;

// glTF's metallic-roughness with tally's diffuse weighting (docs/lighting.md), written
// out from the formulas, one channel.
double mr_reference(double base, double metallic, double roughness, const Vec3& n, const Vec3& wo, const Vec3& wi) {
  const double a = std::max(roughness * roughness, 1e-3), a2 = a * a;
  const double co = dot(n, wo), ci = dot(n, wi);
  const Vec3 h = normalize(wo + wi);
  const double ch = dot(n, h);
  const double D = a2 / (kPi * std::pow(ch * ch * (a2 - 1) + 1, 2));
  auto lambda = [&](double c) { return 0.5 * (std::sqrt(1 + a2 * (1 - c * c) / (c * c)) - 1); };
  const double G2 = 1 / (1 + lambda(co) + lambda(ci));
  const double f0 = 0.04 * (1 - metallic) + base * metallic;
  const double F = f0 + (1 - f0) * std::pow(1 - dot(wo, h), 5);
  const double Fd_o = 0.04 + 0.96 * std::pow(1 - co, 5), Fd_i = 0.04 + 0.96 * std::pow(1 - ci, 5);
  return F * D * G2 / (4 * co * ci) + (1 - metallic) * base / kPi * (1 - Fd_o) * (1 - Fd_i);
}

// glTF 2.0's reference form (Appendix B), written out from the specification, one
// channel: mix(fresnel_mix(ior 1.5, base / pi, S), conductor_fresnel(base, S), metallic)
// with F at w_o.h for both the layer and the base.
double mr_gltf_reference(double base, double metallic, double roughness, const Vec3& n, const Vec3& wo, const Vec3& wi) {
  const double a = std::max(roughness * roughness, 1e-3), a2 = a * a;
  const double co = dot(n, wo), ci = dot(n, wi);
  const Vec3 h = normalize(wo + wi);
  const double ch = dot(n, h), voh = dot(wo, h);
  const double D = a2 / (kPi * std::pow(ch * ch * (a2 - 1) + 1, 2));
  auto lambda = [&](double c) { return 0.5 * (std::sqrt(1 + a2 * (1 - c * c) / (c * c)) - 1); };
  const double S = D / (1 + lambda(co) + lambda(ci)) / (4 * co * ci);
  const double Fd = 0.04 + 0.96 * std::pow(1 - voh, 5);
  const double Fm = base + (1 - base) * std::pow(1 - voh, 5);
  const double dielectric = (1 - Fd) * base / kPi + Fd * S;
  const double metal = Fm * S;
  return (1 - metallic) * dielectric + metallic * metal;
}

json point_query(const json& scene, const json& material, const Vec3& wo, const std::vector<std::string>& est,
                 uint64_t samples) {
  return {{"kind", "lighting"}, {"seed", 11}, {"scene", scene},
          {"query", {{"type", "points"},
                     {"points", json::array({{{"p", {0, 0, 0}}, {"n", {0, 0, 1}}, {"wo", test::vec(wo)}, {"material", material}}})}}},
          {"estimators", est}, {"stop", {{"max_samples", samples}}}};
}

TEST(GlossyScene, PointLightOnGgxIsTheClosedForm) {
  const Vec3 n{0, 0, 1};
  const Vec3 wo = normalize(Vec3{0.6, 0.1, 0.8});
  const Vec3 light{-1.0, 0.3, 1.5};
  const double I = 4.0;
  const json scene = {{"lights", json::array({{{"type", "point"}, {"position", test::vec(light)}, {"intensity", {I, I, I}}}})}};
  struct Case {
    double base, metallic, roughness;
  };
  for (const Case c : {Case{0.9, 1.0, 0.3}, Case{0.5, 0.3, 0.7}, Case{0.8, 0.0, 0.15}, Case{0.2, 0.6, 1.0}}) {
    const json mat = {{"type", "metallic_roughness"}, {"base_color", {c.base, c.base, c.base}},
                      {"metallic", c.metallic}, {"roughness", c.roughness}};
    const Vec3 d = light;  // from the origin
    const double d2 = dot(d, d);
    const Vec3 wi = d / std::sqrt(d2);
    // JSON materials are energy-conserving unless the scene's material_model says otherwise.
    for (const char* model : {"", "energy_conserving", "gltf_reference"}) {
      json sc = scene;
      if (*model) sc["material_model"] = model;
      const test::JobRun r = test::run_spec(point_query(sc, mat, wo, {"mis"}, 4));
      const double f = std::string(model) == "gltf_reference" ? mr_gltf_reference(c.base, c.metallic, c.roughness, n, wo, wi)
                                                             : mr_reference(c.base, c.metallic, c.roughness, n, wo, wi);
      const double expect = f * I * dot(n, wi) / d2;
      EXPECT_NEAR(r.channel(0).mean, expect, 1e-12 * expect) << c.base << " " << c.metallic << " " << c.roughness << " " << model;
      EXPECT_EQ(r.channel(0).m2, 0.0);  // deterministic
    }
    // The two forms differ wherever the base is not pure metal.
    if (c.metallic < 1.0) {
      EXPECT_GT(std::fabs(mr_gltf_reference(c.base, c.metallic, c.roughness, n, wo, wi) -
                          mr_reference(c.base, c.metallic, c.roughness, n, wo, wi)),
                1e-3 * mr_reference(c.base, c.metallic, c.roughness, n, wo, wi));
    }
  }
  // The plan: glossy is not delta (specular off, and says why); shadows and light
  // samples stay what a diffuse receiver needs.
  {
    const json mat = {{"type", "ggx"}, {"reflectance", {0.9, 0.9, 0.9}}, {"roughness", 0.3}};
    const test::JobRun r = test::run_spec(point_query(scene, mat, wo, {"mis"}, 4));
    bool seen = false;
    const json plan = plan_json(*r.job);
    for (const json& e : plan["plan"]["effects"]) {
      if (e["effect"] != "specular") continue;
      seen = true;
      EXPECT_FALSE(e["on"].get<bool>());
      EXPECT_NE(e["why"].get<std::string>().find("glossy surfaces are sampled"), std::string::npos) << e.dump();
    }
    EXPECT_TRUE(seen);
  }
  // "ggx" is the metal: F0 = reflectance.
  const json ggx = {{"type", "ggx"}, {"reflectance", {0.9, 0.9, 0.9}}, {"roughness", 0.3}};
  const json mr = {{"type", "metallic_roughness"}, {"base_color", {0.9, 0.9, 0.9}}, {"metallic", 1.0}, {"roughness", 0.3}};
  EXPECT_EQ(test::run_spec(point_query(scene, ggx, wo, {"mis"}, 4)).channel(0).mean,
            test::run_spec(point_query(scene, mr, wo, {"mis"}, 4)).channel(0).mean);
}

TEST(GlossyScene, EstimatorsAgreeUnderAnAreaLight) {
  // A glossy receiver seeing a quad light near its mirror direction: light sampling,
  // BSDF sampling (cosine / uniform) and MIS with the mixture pdf estimate one integral.
  // 3 comparisons at 4 sd of the difference (false-failure rate ~2e-4).
  const json scene = {{"materials", {{"lamp", test::emitter(3.0)}}},
                      {"shapes", json::array({{{"type", "quad"}, {"corner", {-1.4, -0.5, 2}}, {"edge_u", {0, 1, 0}},
                                               {"edge_v", {1, 0, 0}}, {"material", "lamp"}}})}};
  const json mat = {{"type", "metallic_roughness"}, {"base_color", {0.7, 0.7, 0.7}}, {"metallic", 0.5}, {"roughness", 0.4}};
  const Vec3 wo = normalize(Vec3{0.45, 0, 1});
  const test::JobRun r = test::run_spec(point_query(scene, mat, wo, {"uniform_hemisphere", "cosine_hemisphere", "light_area", "mis"}, 400000));
  // Channels: (estimator * points + point) * 3 + rgb, one point.
  auto mean = [&](size_t e) { return r.channel(e * 3).mean; };
  auto se = [&](size_t e) { return std::sqrt(r.channel(e * 3).variance() / static_cast<double>(r.channel(e * 3).n)); };
  ASSERT_GT(mean(3), 0.0);
  for (size_t e : {0u, 1u, 2u}) {
    EXPECT_NEAR(mean(e), mean(3), 4.0 * std::hypot(se(e), se(3))) << "estimator " << e;
  }
  // MIS with a glossy lobe beats light sampling alone here.
  EXPECT_LT(se(3), se(2));
}

TEST(GlossyScene, ShadingNormalsShade) {
  // A glTF quad facing +z whose vertex normals all lean 30 degrees towards +x, seen from
  // straight above through a very narrow camera, lit by a directional light from +z:
  // the pixel is f(n_s; w_o, w_i) E cos(n_s, w_i) with the shading normal n_s (the
  // camera ray's spread changes w_o by < 1e-5), not the flat value. f is glTF's
  // reference form (the default for glTF materials), and tally's energy-conserving
  // form when the scene's material_model asks for it.
  namespace fs = std::filesystem;
  const fs::path dir = fs::temp_directory_path() / "tally_gltf_shading_normals";
  fs::remove_all(dir);
  fs::create_directories(dir);
  const double a = 30.0 * kPi / 180.0;
  const float sx = static_cast<float>(std::sin(a)), cz = static_cast<float>(std::cos(a));
  test::GltfWriter w;
  const int mat = w.material({{"pbrMetallicRoughness", {{"baseColorFactor", {0.5, 0.5, 0.5, 1.0}}, {"metallicFactor", 0.0},
                                                         {"roughnessFactor", 0.6}}}});
  const int mesh = w.mesh({-1, -1, 0, 1, -1, 0, 1, 1, 0, -1, 1, 0}, {0, 1, 2, 0, 2, 3}, mat,
                          {sx, 0, cz, sx, 0, cz, sx, 0, cz, sx, 0, cz});
  w.node({{"mesh", mesh}});
  w.doc["cameras"] = {{{"type", "perspective"}, {"perspective", {{"yfov", 1e-5}, {"znear", 0.01}}}}};
  w.node({{"camera", 0}, {"translation", {0, 0, 3}}});
  w.save_gltf(dir, "n");
  JobLimits limits;
  limits.asset_dir = dir.string();
  const double E = 2.0;
  const json scene = {{"shapes", json::array({{{"type", "gltf"}, {"file", "n.gltf"}, {"camera", 0}, {"resolution", {1, 1}}}})},
                      {"lights", json::array({{{"type", "directional"}, {"direction", {0, 0, 1}}, {"irradiance", {E, E, E}}}})}};
  const json spec = {{"kind", "lighting"}, {"seed", 5}, {"scene", scene},
                     {"query", {{"type", "image"}, {"max_depth", 1}}}, {"estimators", {"mis"}}, {"stop", {{"max_samples", 8}}}};
  const test::JobRun r = test::run_spec(spec, 1, limits);
  const Vec3 ns = normalize(Vec3{static_cast<double>(sx), 0, static_cast<double>(cz)});
  const Vec3 up{0, 0, 1};
  const double shaded = mr_gltf_reference(0.5, 0.0, 0.6, ns, up, up) * E * dot(ns, up);
  const double flat = mr_gltf_reference(0.5, 0.0, 0.6, up, up, up) * E;
  EXPECT_NEAR(r.channel(0).mean, shaded, 1e-4 * shaded);
  EXPECT_GT(std::fabs(shaded - flat), 0.05 * flat);
  json ec = spec;
  ec["scene"]["material_model"] = "energy_conserving";
  const test::JobRun r2 = test::run_spec(ec, 1, limits);
  const double shaded_ec = mr_reference(0.5, 0.0, 0.6, ns, up, up) * E * dot(ns, up);
  EXPECT_NEAR(r2.channel(0).mean, shaded_ec, 1e-4 * shaded_ec);
  EXPECT_GT(std::fabs(shaded - shaded_ec), 1e-3 * shaded);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace tally
