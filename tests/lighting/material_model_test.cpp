// glTF materials as their authors saw them (issue 29): glTF's reference form is the
// default for glTF files and the energy-conserving form stays selectable by the scene's
// "material_model"; KHR_materials_specular with specularFactor 0 is a Lambertian surface
// (a white furnace through the whole pipeline: a plane under a uniform sky returns its
// albedo); the NEAREST sampler filter returns one texel's value; bad input names the field.
#include <gtest/gtest.h>

#include <cmath>
#include <string>

#include "common/lighting/texture.hpp"
#include "lighting/gltf/gltf_writer.hpp"
#include "lighting/lighting_test_support.hpp"

namespace tally {
namespace {

using json = nlohmann::json;
using test::GltfWriter;

// A unit quad at z = 0 facing +z (base colour 0.5, metallic 0, roughness 0.5, the
// given material extensions), seen obliquely (60 degrees from the normal) by a narrow
// camera, so every pixel sees the quad.
GltfWriter plane_gltf(const json& extensions) {
  GltfWriter w;
  json m = {{"pbrMetallicRoughness", {{"baseColorFactor", {0.5, 0.5, 0.5, 1.0}}, {"metallicFactor", 0.0},
                                      {"roughnessFactor", 0.5}}}};
  if (!extensions.empty()) m["extensions"] = extensions;
  const int mat = w.material(m);
  w.node({{"mesh", w.mesh({-1, -1, 0, 1, -1, 0, 1, 1, 0, -1, 1, 0}, {0, 1, 2, 0, 2, 3}, mat)}});
  w.doc["cameras"] = {{{"type", "perspective"}, {"perspective", {{"yfov", 0.05}, {"znear", 0.01}}}}};
  // At (0, -3 sin 60, 3 cos 60) looking at the origin: rotation about +x by 60 degrees.
  const double a = kPi / 3.0;
  w.node({{"camera", 0},
          {"translation", {0.0, -3.0 * std::sin(a), 3.0 * std::cos(a)}},
          {"rotation", {std::sin(a / 2), 0.0, 0.0, std::cos(a / 2)}}});
  return w;
}

json sky_spec(const std::string& file, const json& extra = json::object()) {
  json scene = {{"shapes", json::array({{{"type", "gltf"}, {"file", file}, {"camera", 0}, {"resolution", {4, 4}}}})},
                {"lights", json::array({{{"type", "sky"}, {"radiance", {1.0, 1.0, 1.0}}}})}};
  scene.update(extra);
  return {{"kind", "lighting"}, {"seed", 9}, {"scene", scene},
          {"query", {{"type", "image"}, {"max_depth", 1}, {"tile_size", 4}}},
          {"estimators", {"mis"}}, {"stop", {{"max_samples", 64}}}};
}

struct Mean {
  double mean = 0, se = 0;
};
// The green channel over the image: the mean of the pixel means and its standard error.
Mean image_green(const test::JobRun& r) {
  const auto& ch = r.runner->state().channels;
  double s = 0, v = 0;
  size_t k = 0;
  for (size_t c = 1; c < ch.size(); c += 3, ++k) {
    s += ch[c].mean;
    v += ch[c].variance() / static_cast<double>(ch[c].n);
  }
  return {s / static_cast<double>(k), std::sqrt(v) / static_cast<double>(k)};
}

TEST(MaterialModel, SpecularFactorZeroPlaneUnderUniformSkyReturnsItsAlbedo) {
  // A Lambertian plane under a uniform sky of radiance L reflects L x albedo in every
  // direction (∫ albedo/pi L cos dw = albedo L). With KHR_materials_specular
  // specularFactor 0 the glTF material is that plane: 0.5 within 4 se (the MIS
  // estimator's samples are all 0.5 up to rounding here, so se is ~0: 1e-12 floor).
  // Without the extension glTF's reference form adds a specular layer: seen 60 degrees
  // off the normal it reflects more than the albedo (the diffuse term is weighted by
  // 1 - F(w_o.h) ~ 0.96 and the specular lobe adds ~0.1), more than 4 se away.
  test::AssetSandbox dir("tally_material_model_furnace");
  plane_gltf({{"KHR_materials_specular", {{"specularFactor", 0.0}}}}).save_gltf(dir.assets(), "lambert");
  plane_gltf(json::object()).save_gltf(dir.assets(), "plain");
  const Mean lambert = image_green(test::run_spec(sky_spec("lambert.gltf"), 1, dir.limits()));
  EXPECT_NEAR(lambert.mean, 0.5, std::max(4.0 * lambert.se, 1e-12));
  // The same under the energy-conserving form: no specular layer, no coating loss.
  const Mean lambert_ec = image_green(
      test::run_spec(sky_spec("lambert.gltf", {{"material_model", "energy_conserving"}}), 1, dir.limits()));
  EXPECT_NEAR(lambert_ec.mean, 0.5, std::max(4.0 * lambert_ec.se, 1e-12));
  const Mean plain = image_green(test::run_spec(sky_spec("plain.gltf"), 1, dir.limits()));
  EXPECT_GT(plain.mean, 0.5 + 4.0 * plain.se + 0.02);
  // The energy-conserving form of the same plain material reflects less than the albedo
  // (the coating takes its share on the way in and out).
  const Mean plain_ec = image_green(
      test::run_spec(sky_spec("plain.gltf", {{"material_model", "energy_conserving"}}), 1, dir.limits()));
  EXPECT_LT(plain_ec.mean, plain.mean - 4.0 * std::hypot(plain.se, plain_ec.se));
}

TEST(MaterialModel, NearestLookupBetweenTexelCentresReturnsOneTexel) {
  // A 2x2 texture a b / c d. Bilinear at the image centre (0.5, 0.5) is the average of
  // the four; nearest is the texel whose cell holds uv: (floor(u W), floor(v H)) = (1, 1),
  // d exactly. Between two centres: (0.5, 0.25) -> texel (1, 0) = b; just left of
  // u = 0.5 -> a. Wrapping: u = 1.25 (repeat) -> column 0, clamp -> column 1.
  auto g = std::make_shared<TexelGrid>();
  g->width = g->height = 2;
  for (float r : {0.125f, 0.375f, 0.625f, 0.875f}) g->rgb.insert(g->rgb.end(), {r, 2 * r, 4 * r});
  Texture t;
  t.texels = g;
  EXPECT_EQ(t.lookup({0.5, 0.5}).x, (0.125 + 0.375 + 0.625 + 0.875) / 4);
  t.filter = TextureFilter::nearest;
  struct Case {
    double u, v, want;
    TextureWrap wrap;
  };
  for (const Case& c : {Case{0.5, 0.5, 0.875, TextureWrap::repeat}, Case{0.5, 0.25, 0.375, TextureWrap::repeat},
                        Case{0.4999, 0.25, 0.125, TextureWrap::repeat}, Case{0.25, 0.75, 0.625, TextureWrap::repeat},
                        Case{1.25, 0.25, 0.125, TextureWrap::repeat}, Case{1.25, 0.25, 0.375, TextureWrap::clamp_to_edge},
                        Case{-0.25, 0.25, 0.375, TextureWrap::repeat}, Case{1.25, 0.25, 0.375, TextureWrap::mirrored_repeat}}) {
    t.wrap_s = c.wrap;
    const Rgb got = t.lookup({c.u, c.v});
    EXPECT_EQ(got.x, c.want) << c.u << ", " << c.v << " wrap " << static_cast<int>(c.wrap);
    EXPECT_EQ(got.y, 2 * c.want);
    EXPECT_EQ(got.z, 4 * c.want);
  }
}

TEST(MaterialModel, BadInputNamesTheField) {
  test::AssetSandbox dir("tally_material_model_bad");
  EXPECT_EQ(test::scene_error({{"material_model", "phong"}}, dir.limits()).rfind("/scene/material_model:", 0), 0u)
      << test::scene_error({{"material_model", "phong"}}, dir.limits());
  EXPECT_NE(test::scene_error({{"material_model", 1}}, dir.limits()).find("/scene/material_model"), std::string::npos);
  struct Bad {
    json ext;
    std::string field;
  };
  for (const Bad& b : {Bad{{{"specularFactor", 2.0}}, "/specularFactor"},
                       Bad{{{"specularFactor", "x"}}, "/specularFactor"},
                       Bad{{{"specularColorFactor", {1.0, -1.0, 1.0}}}, "/specularColorFactor/1"},
                       Bad{{{"specularColorFactor", {1.0, 1.0}}}, "/specularColorFactor"},
                       Bad{{{"specularTexture", {{"index", 0}}}}, "/specularTexture"},
                       Bad{{{"specularColorTexture", {{"index", "a"}}}}, "/specularColorTexture/index"}}) {
    plane_gltf({{"KHR_materials_specular", b.ext}}).save_gltf(dir.assets(), "bad");
    const std::string err = test::scene_error({{"shapes", json::array({{{"type", "gltf"}, {"file", "bad.gltf"}}})}},
                                              dir.limits());
    EXPECT_NE(err.find("/materials/0/extensions/KHR_materials_specular" + b.field), std::string::npos) << err;
    EXPECT_EQ(err.rfind("/scene/shapes/0/file", 0), 0u) << err;
  }
  // Parsed values land in the material; the reference form is the glTF default.
  plane_gltf({{"KHR_materials_specular", {{"specularFactor", 0.25}, {"specularColorFactor", {1.0, 0.5, 2.0}}}}})
      .save_gltf(dir.assets(), "good");
  const Scene s = test::parse_scene_json({{"shapes", json::array({{{"type", "gltf"}, {"file", "good.gltf"}}})}},
                                         dir.limits());
  ASSERT_EQ(s.materials.size(), 1u);
  EXPECT_EQ(s.materials[0].specular, 0.25);
  EXPECT_EQ(s.materials[0].specular_color.z, 2.0);
  EXPECT_EQ(s.materials[0].model, MaterialModel::gltf_reference);
  const Scene e = test::parse_scene_json(
      {{"material_model", "energy_conserving"}, {"shapes", json::array({{{"type", "gltf"}, {"file", "good.gltf"}}})}},
      dir.limits());
  EXPECT_EQ(e.materials[0].model, MaterialModel::energy_conserving);
  const Scene j = test::parse_scene_json({{"materials", {{"m", {{"type", "metallic_roughness"}, {"base_color", {1, 1, 1}},
                                                                {"metallic", 0}, {"roughness", 1}}}}}},
                                         dir.limits());
  EXPECT_EQ(j.materials[0].model, MaterialModel::energy_conserving);
}

}  // namespace
}  // namespace tally
