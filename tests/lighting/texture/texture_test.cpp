// Image textures (common/lighting/texture.*, issue 16): the sampler against hand-computed
// bilinear values in each glTF wrap mode, sRGB decoding against the closed-form EOTF, a
// constant texture rendering bit for bit like the untextured material (glTF base colour,
// metallic-roughness and emissive; external file, .glb buffer view and data URI), a
// checker through an OBJ .mtl map_Kd matching the texel colours exactly, 1 vs 2 threads
// bit-identical, and bad inputs failing with errors naming the field. Every texture file
// is written here with OpenImageIO.
#include <gtest/gtest.h>

#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>

#include "common/image/image_decode.hpp"
#include "common/image/image_io.hpp"
#include "common/lighting/scene_json.hpp"
#include "common/lighting/texture.hpp"
#include "lighting/gltf/gltf_writer.hpp"
#include "lighting/lighting_test_support.hpp"
#include "support/requested_image_module.hpp"

namespace tally {
namespace {

namespace fs = std::filesystem;
namespace OIIO = OIIO_NAMESPACE;
using json = nlohmann::json;
using test::GltfWriter;
using TempDir = test::AssetSandbox;

// An 8-bit image file (PNG, or any format OpenImageIO writes by the name's extension).
std::string encode(const std::string& name, int w, int h, int nc, const std::vector<uint8_t>& px) {
  std::vector<unsigned char> buf;
  OIIO::Filesystem::IOVecOutput proxy(buf);
  auto out = OIIO::ImageOutput::create(name, &proxy);
  EXPECT_TRUE(out) << OIIO::geterror();
  OIIO::ImageSpec spec(w, h, nc, OIIO::TypeDesc::UINT8);
  spec.attribute("oiio:UnassociatedAlpha", 1);  // store the values as given (no un-premultiplying)
  EXPECT_TRUE(out->open(name, spec)) << out->geterror();
  EXPECT_TRUE(out->write_image(OIIO::TypeDesc::UINT8, px.data())) << out->geterror();
  out->close();
  return {buf.begin(), buf.end()};
}
std::string constant_png(uint8_t r, uint8_t g, uint8_t b, int w = 4, int h = 4) {
  std::vector<uint8_t> px;
  for (int i = 0; i < w * h; ++i) px.insert(px.end(), {r, g, b});
  return encode("c.png", w, h, 3, px);
}
void write_file(const fs::path& p, const std::string& bytes) { std::ofstream(p, std::ios::binary) << bytes; }

std::string base64(const std::string& in) {
  static const char* k = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  size_t i = 0;
  for (; i + 2 < in.size(); i += 3) {
    const uint32_t v = (uint8_t(in[i]) << 16) | (uint8_t(in[i + 1]) << 8) | uint8_t(in[i + 2]);
    for (int s = 18; s >= 0; s -= 6) out.push_back(k[(v >> s) & 63]);
  }
  if (i < in.size()) {
    uint32_t v = uint8_t(in[i]) << 16;
    if (i + 1 < in.size()) v |= uint8_t(in[i + 1]) << 8;
    out.push_back(k[(v >> 18) & 63]);
    out.push_back(k[(v >> 12) & 63]);
    out.push_back(i + 1 < in.size() ? k[(v >> 6) & 63] : '=');
    out.push_back('=');
  }
  return out;
}

Scene parse(const json& scene, const JobLimits& limits) {
  SpecReader r(scene, "/scene");
  return parse_scene(r, limits);
}
std::string error_of(const json& scene, const JobLimits& limits) {
  try {
    parse(scene, limits);
  } catch (const SpecError& e) {
    return e.what();
  }
  return "";
}

void expect_bit_identical(const test::JobRun& a, const test::JobRun& b) {
  EXPECT_EQ(test::differing_channels(a, b), 0u)
      << "of " << a.runner->state().channels.size() + a.runner->state().sums.size() << " channels";
}

// --- the sampler -----------------------------------------------------------------------

// 2x2 texels, R channel: a = 0 (top left), b = 1 (top right), c = 2, d = 4 (bottom row);
// G = 10 R, B = -R (the sampler does not care about signs).
Texture two_by_two(TextureWrap s, TextureWrap t) {
  auto g = std::make_shared<TexelGrid>();
  g->width = g->height = 2;
  for (double r : {0.0, 1.0, 2.0, 4.0}) {
    g->rgb.insert(g->rgb.end(), {static_cast<float>(r), static_cast<float>(10 * r), static_cast<float>(-r)});
  }
  Texture tex;
  tex.texels = g;
  tex.wrap_s = s;
  tex.wrap_t = t;
  return tex;
}

TEST(Texture, BilinearLookupAndEachWrapModeMatchHandComputedValues) {
  using W = TextureWrap;
  struct Case {
    W s, t;
    double u, v, r;
  };
  const Case cases[] = {
      // Texel centres and bilinear interior (any mode).
      {W::repeat, W::repeat, 0.25, 0.25, 0.0},
      {W::repeat, W::repeat, 0.75, 0.75, 4.0},
      {W::repeat, W::repeat, 0.5, 0.25, 0.5},     // halfway a -> b
      {W::repeat, W::repeat, 0.5, 0.5, 1.75},     // (0 + 1 + 2 + 4) / 4
      {W::repeat, W::repeat, 0.375, 0.5, 1.375},  // fx = 1/4: rows 0.25 and 2.5, then halfway
      {W::clamp_to_edge, W::clamp_to_edge, 0.375, 0.5, 1.375},
      {W::mirrored_repeat, W::mirrored_repeat, 0.375, 0.5, 1.375},
      // u = 0: halfway between texel -1 and texel 0.
      {W::repeat, W::repeat, 0.0, 0.25, 0.5},           // texel -1 = b
      {W::clamp_to_edge, W::repeat, 0.0, 0.25, 0.0},    // texel -1 = a
      {W::mirrored_repeat, W::repeat, 0.0, 0.25, 0.0},  // texel -1 = a (mirror)
      // u = 1: halfway between texel 1 and texel 2.
      {W::repeat, W::repeat, 1.0, 0.25, 0.5},           // texel 2 = a
      {W::clamp_to_edge, W::repeat, 1.0, 0.25, 1.0},    // texel 2 = b
      {W::mirrored_repeat, W::repeat, 1.0, 0.25, 1.0},  // texel 2 = b (mirror)
      // Outside [0, 1].
      {W::repeat, W::repeat, 1.25, 0.25, 0.0},            // = 0.25
      {W::clamp_to_edge, W::repeat, 1.25, 0.25, 1.0},     // edge texel b
      {W::mirrored_repeat, W::repeat, 1.25, 0.25, 1.0},   // = 0.75
      {W::repeat, W::repeat, -0.25, 0.25, 1.0},           // = 0.75
      {W::clamp_to_edge, W::repeat, -0.25, 0.25, 0.0},    // edge texel a
      {W::mirrored_repeat, W::repeat, -0.25, 0.25, 0.0},  // = 0.25
      {W::mirrored_repeat, W::repeat, 1.625, 0.25, 0.25},  // = 0.375: a + (b - a) / 4
      {W::repeat, W::repeat, -3.75, 0.25, 0.0},
      {W::repeat, W::repeat, 1e9 + 0.75, 0.25, 1.0},
      {W::mirrored_repeat, W::repeat, 1e9 + 0.75, 0.25, 1.0},  // 1e9 is an even number of periods
      {W::clamp_to_edge, W::repeat, -1e30, 0.25, 0.0},
      // The v axis has its own mode.
      {W::repeat, W::clamp_to_edge, 0.25, 1.0, 2.0},     // below the bottom row: c
      {W::repeat, W::repeat, 0.25, 1.0, 1.0},            // halfway c -> a
      {W::repeat, W::mirrored_repeat, 0.25, -0.25, 0.0},  // = 0.25
  };
  for (const Case& c : cases) {
    const Texture tex = two_by_two(c.s, c.t);
    const Rgb got = tex.lookup({c.u, c.v});
    const double want = c.r;
    EXPECT_EQ(got.x, want) << "wrap " << int(c.s) << "/" << int(c.t) << " at (" << c.u << ", " << c.v << ")";
    EXPECT_EQ(got.y, 10 * want);
    EXPECT_EQ(got.z, -want);
  }
  // The texel index maps of the three modes.
  EXPECT_EQ(wrap_texel(-1, 3, TextureWrap::repeat), 2);
  EXPECT_EQ(wrap_texel(3, 3, TextureWrap::repeat), 0);
  EXPECT_EQ(wrap_texel(-7, 3, TextureWrap::repeat), 2);
  EXPECT_EQ(wrap_texel(-1, 3, TextureWrap::clamp_to_edge), 0);
  EXPECT_EQ(wrap_texel(5, 3, TextureWrap::clamp_to_edge), 2);
  for (int64_t i = -6, k = 0; i < 6; ++i, ++k) {
    // mirrored repeat, n = 3: ... 0 1 2 2 1 0 | 0 1 2 2 1 0 ...
    const int64_t want[] = {0, 1, 2, 2, 1, 0};
    EXPECT_EQ(wrap_texel(i, 3, TextureWrap::mirrored_repeat), want[k % 6]) << i;
  }
}

TEST(Texture, SrgbDecodingMatchesTheClosedFormEotf) {
  const std::vector<uint8_t> codes = {0, 1, 10, 11, 64, 128, 200, 254, 255};
  std::vector<uint8_t> px;
  for (uint8_t c : codes) px.insert(px.end(), {c, c, c});
  const std::string png = encode("row.png", static_cast<int>(codes.size()), 1, 3, px);
  const auto srgb = decode_texels(png, true, 1 << 20);
  const auto linear = decode_texels(png, false, 1 << 20);
  ASSERT_EQ(srgb->width, static_cast<int>(codes.size()));
  for (size_t i = 0; i < codes.size(); ++i) {
    const double c = codes[i] / 255.0;
    // IEC 61966-2-1, written out here independently of srgb_eotf.
    const double want = c <= 0.04045 ? c / 12.92 : std::pow((c + 0.055) / 1.055, 2.4);
    EXPECT_EQ(srgb->rgb[3 * i], static_cast<float>(want)) << int(codes[i]);
    EXPECT_EQ(linear->rgb[3 * i + 1], static_cast<float>(c)) << int(codes[i]);
  }
  EXPECT_EQ(srgb->rgb[0], 0.0f);
  EXPECT_EQ(srgb->rgb[3 * 8], 1.0f);
  EXPECT_NEAR(srgb->rgb[3 * 5], 0.2158605, 1e-7);  // 128: the textbook value
  EXPECT_NEAR(srgb->rgb[3 * 2], 10.0 / 255.0 / 12.92, 1e-9);  // the linear segment
  EXPECT_EQ(srgb->bytes(), codes.size() * 12);
  // Grey and grey + alpha files give grey texels; alpha is ignored.
  const auto grey = decode_texels(encode("g.png", 2, 1, 2, {128, 7, 255, 9}), true, 16);
  EXPECT_EQ(grey->rgb[0], srgb->rgb[3 * 5]);
  EXPECT_EQ(grey->rgb[2], srgb->rgb[3 * 5]);
  EXPECT_EQ(grey->rgb[3], 1.0f);
  // JPEG through the OpenImageIO module (the OpenEXR + libpng module decodes PNG only):
  // a constant grey 128 comes back within JPEG's rounding (+-2 codes).
  if (image_module_backend().rfind("OpenImageIO", 0) == 0) {
    const std::string jpg = encode("c.jpg", 8, 8, 3, std::vector<uint8_t>(8 * 8 * 3, 128));
    const auto j = decode_texels(jpg, true, 64);
    ASSERT_EQ(j->width, 8);
    EXPECT_GE(j->rgb[0], static_cast<float>(std::pow((126 / 255.0 + 0.055) / 1.055, 2.4)));
    EXPECT_LE(j->rgb[0], static_cast<float>(std::pow((130 / 255.0 + 0.055) / 1.055, 2.4)));
  } else {
    try {
      decode_texels(encode("c.jpg", 8, 8, 3, std::vector<uint8_t>(8 * 8 * 3, 128)), true, 64);
      ADD_FAILURE() << "the OpenEXR module decoded a JPEG";
    } catch (const std::runtime_error& e) {
      EXPECT_NE(std::string(e.what()).find("only, not jpeg"), std::string::npos) << e.what();
    }
  }
  // The pixel limit is checked before decoding.
  try {
    decode_texels(png, true, 8);
    ADD_FAILURE() << "9 pixels over a limit of 8 were decoded";
  } catch (const std::runtime_error& e) {
    EXPECT_STREQ(e.what(), "the image has 9x1 pixels, more than the limit of 8");
  }
}

// --- glTF: a constant texture is the untextured material ------------------------------

// A floor (metallic-roughness, textured base colour and metallic-roughness) and an
// emissive panel (textured emission) seen by a camera, lit by a point light and the
// panel. `textured`: factors x constant textures; else the products as plain factors.
struct Factors {
  std::array<double, 3> base{0.8, 0.6, 0.4}, emissive{1.0, 0.75, 0.5};
  double metallic = 0.9, roughness = 0.7, strength = 3.0;
};

enum class ImageStore { file, buffer_view, data_uri };

GltfWriter textured_gltf(const Factors& f, bool textured, ImageStore store, const std::array<std::string, 3>& pngs) {
  GltfWriter w;
  json floor = {{"pbrMetallicRoughness", {{"baseColorFactor", {f.base[0], f.base[1], f.base[2], 1.0}},
                                          {"metallicFactor", f.metallic}, {"roughnessFactor", f.roughness}}}};
  json panel = {{"pbrMetallicRoughness", {{"baseColorFactor", {0.25, 0.25, 0.25, 1.0}}, {"metallicFactor", 0.0}}},
                {"emissiveFactor", {f.emissive[0], f.emissive[1], f.emissive[2]}},
                {"extensions", {{"KHR_materials_emissive_strength", {{"emissiveStrength", f.strength}}}}}};
  if (textured) {
    for (int i = 0; i < 3; ++i) {
      json image;
      if (store == ImageStore::file) {
        image = {{"uri", "tex" + std::to_string(i) + ".png"}};
      } else if (store == ImageStore::buffer_view) {
        image = {{"bufferView", w.view(pngs[static_cast<size_t>(i)].data(), pngs[static_cast<size_t>(i)].size())},
                 {"mimeType", "image/png"}};
      } else {
        image = {{"uri", "data:image/png;base64," + base64(pngs[static_cast<size_t>(i)])}};
      }
      w.doc["images"].push_back(image);
      w.doc["textures"].push_back({{"source", i}, {"sampler", 0}});
    }
    w.doc["samplers"] = {{{"wrapS", 33071}, {"wrapT", 33648}}};
    floor["pbrMetallicRoughness"]["baseColorTexture"] = {{"index", 0}};
    floor["pbrMetallicRoughness"]["metallicRoughnessTexture"] = {{"index", 1}, {"texCoord", 0}};
    panel["emissiveTexture"] = {{"index", 2}};
  }
  const int mf = w.material(floor), mp = w.material(panel);
  const std::vector<float> quad_uv = {0, 0, 1, 0, 1, 1, 0, 1};
  w.node({{"mesh", w.mesh({-2, 0, -2, -2, 0, 2, 2, 0, 2, 2, 0, -2}, {0, 1, 2, 0, 2, 3}, mf, {}, {0, 0, 0, 3, 3, 3, 3, 0})}});
  w.node({{"mesh", w.mesh({-0.5, 0, -0.5, 0.5, 0, -0.5, 0.5, 0, 0.5, -0.5, 0, 0.5}, {0, 1, 2, 0, 2, 3}, mp, {}, quad_uv)},
          {"translation", {0, 1.5, 0}}});
  w.doc["cameras"] = {{{"type", "perspective"}, {"perspective", {{"yfov", 0.9}, {"znear", 0.01}}}}};
  w.node({{"camera", 0}, {"translation", {0, 1, 4}}});
  w.light({{"type", "point"}, {"color", {1, 1, 1}}, {"intensity", 3}});
  w.node({{"translation", {1, 2, 1}}, {"extensions", {{"KHR_lights_punctual", {{"light", 0}}}}}});
  return w;
}

json gltf_image_spec(const std::string& file, int spp = 8) {
  json shape = {{"type", "gltf"}, {"file", file}, {"camera", 0}, {"resolution", {16, 12}}};
  return {{"kind", "lighting"}, {"seed", 5}, {"sampler", "sobol"}, {"scene", {{"shapes", json::array({shape})}}},
          {"query", {{"type", "image"}, {"max_depth", 3}, {"tile_size", 8}}},
          {"estimators", {"mis"}}, {"stop", {{"max_samples", spp}}}};
}

TEST(Texture, ConstantTextureRendersBitIdenticalToTheUntexturedMaterial) {
  TempDir dir("tally_tex_constant");
  // base colour sRGB 200/180/150, metallic-roughness linear (G 128 roughness, B 64
  // metalness), emissive sRGB 255/128/30.
  const std::array<std::string, 3> pngs = {constant_png(200, 180, 150), constant_png(0, 128, 64),
                                           constant_png(255, 128, 30)};
  for (int i = 0; i < 3; ++i) write_file(dir.assets() / ("tex" + std::to_string(i) + ".png"), pngs[static_cast<size_t>(i)]);
  const Factors f;
  const GltfWriter tex_file = textured_gltf(f, true, ImageStore::file, pngs);
  tex_file.save_gltf(dir.assets(), "tex_file");
  write_file(dir.assets() / "tex_glb.glb", textured_gltf(f, true, ImageStore::buffer_view, pngs).glb());
  textured_gltf(f, true, ImageStore::data_uri, pngs).save_gltf(dir.assets(), "tex_data");

  // The decoded values the textures hold (checked against the closed form above).
  const Scene s = parse({{"shapes", json::array({{{"type", "gltf"}, {"file", "tex_file.gltf"}}})}}, dir.limits());
  ASSERT_EQ(s.textures.size(), 3u);
  EXPECT_EQ(s.texture_bytes, 3u * 16u * 12u);
  auto texel = [&](int t) { return s.textures[static_cast<size_t>(t)].lookup({0.3, 0.6}); };
  EXPECT_EQ(texel(0).x, static_cast<double>(static_cast<float>(std::pow((200 / 255.0 + 0.055) / 1.055, 2.4))));
  EXPECT_EQ(texel(1).y, static_cast<double>(static_cast<float>(128 / 255.0)));  // linear
  EXPECT_EQ(s.textures[0].wrap_s, TextureWrap::clamp_to_edge);
  EXPECT_EQ(s.textures[0].wrap_t, TextureWrap::mirrored_repeat);
  Factors plain;
  for (int c = 0; c < 3; ++c) {
    plain.base[static_cast<size_t>(c)] = f.base[static_cast<size_t>(c)] * texel(0)[c];
    plain.emissive[static_cast<size_t>(c)] = f.emissive[static_cast<size_t>(c)] * texel(2)[c];
  }
  plain.roughness = f.roughness * texel(1).y;
  plain.metallic = f.metallic * texel(1).z;
  textured_gltf(plain, false, ImageStore::file, pngs).save_gltf(dir.assets(), "plain");

  const test::JobRun ref = test::run_spec(gltf_image_spec("plain.gltf"), 1, dir.limits());
  ASSERT_GT(test::state_total(ref), 0.0);
  for (const std::string file : {"tex_file.gltf", "tex_glb.glb", "tex_data.gltf"}) {
    SCOPED_TRACE(file);
    const test::JobRun got = test::run_spec(gltf_image_spec(file), 1, dir.limits());
    expect_bit_identical(ref, got);
    const json plan = plan_json(*got.job);
    EXPECT_EQ(plan["scene"]["textures"], json({{"count", 3}, {"decoded_bytes", 3 * 16 * 12}}));
  }
  EXPECT_FALSE(plan_json(*ref.job)["scene"].contains("textures"));
}

// --- a checker through .mtl map_Kd: texel colours exactly, 1 vs 2 threads ------------

// A quad filling the view exactly ([-1, 1]^2 at z = 0 seen from z = 2 with
// tan(fov / 2) = 1/2), lit head-on by a directional light of irradiance pi: a pixel's
// radiance is the albedo = Kd x the texture. The texture is 32 x 32 texels of 4 x 4
// checker cells (8 texels each); the image 16 x 16 pixels, so each cell covers 4 x 4
// pixels and the inner 2 x 2 of them see only texels of the cell's colour.
json checker_spec(int spp) {
  json shape = {{"type", "mesh"}, {"obj", "m/quad.obj"}};
  return {{"kind", "lighting"},
          {"seed", 9},
          {"sampler", "independent"},  // one replicate: channel = pixel * 3 + rgb (one tile)
          {"scene", {{"camera", {{"position", {0, 0, 2}}, {"look_at", {0, 0, 0}}, {"up", {0, 1, 0}},
                                 {"fov_deg", 2 * std::atan(0.5) * 180 / kPi}, {"resolution", {16, 16}}}},
                     {"shapes", json::array({shape})},
                     {"lights", json::array({{{"type", "directional"}, {"direction", {0, 0, 1}}, {"irradiance", {kPi, kPi, kPi}}}})}}},
          {"query", {{"type", "image"}, {"max_depth", 1}, {"tile_size", 16}}},
          {"estimators", {"mis"}},
          {"stop", {{"max_samples", spp}}}};
}

void write_checker_obj(const TempDir& dir, const std::string& map_line = "map_Kd tex/checker.png") {
  fs::create_directories(dir.assets() / "m" / "tex");
  std::ofstream(dir.assets() / "m" / "quad.obj") << "mtllib quad.mtl\n"
                                                  << "v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\n"
                                                  << "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
                                                  << "usemtl checker\nf 1/1 2/2 3/3\nf 1/1 3/3 4/4\n";
  std::ofstream(dir.assets() / "m" / "quad.mtl") << "newmtl checker\nKd 1 1 1\nKs 0 0 0\n" << map_line << "\n";
  std::vector<uint8_t> px;
  for (int y = 0; y < 32; ++y) {
    for (int x = 0; x < 32; ++x) {
      const bool light = ((x / 8) + (y / 8)) % 2 == 0;
      // light cells white; dark cells sRGB (64, 128, 192)
      if (light) {
        px.insert(px.end(), {255, 255, 255});
      } else {
        px.insert(px.end(), {64, 128, 192});
      }
    }
  }
  write_file(dir.assets() / "m" / "tex" / "checker.png", encode("checker.png", 32, 32, 3, px));
}

TEST(Texture, MtlCheckerMatchesTexelColoursAndThreadsAgreeBitForBit) {
  TempDir dir("tally_tex_checker");
  write_checker_obj(dir);
  const test::JobRun one = test::run_spec(checker_spec(16), 1, dir.limits());
  auto eotf = [](double code) {
    const double c = code / 255.0;
    return static_cast<double>(static_cast<float>(c <= 0.04045 ? c / 12.92 : std::pow((c + 0.055) / 1.055, 2.4)));
  };
  const double dark[3] = {eotf(64), eotf(128), eotf(192)};
  const auto& ch = one.runner->state().channels;
  int checked = 0;
  for (int py = 0; py < 16; ++py) {
    for (int px = 0; px < 16; ++px) {
      if (px % 4 == 0 || px % 4 == 3 || py % 4 == 0 || py % 4 == 3) continue;  // cell borders blend
      // Image row 0 is the top (y = +1), OBJ vt v = 1 there, texture row 0: cell (px/4, py/4).
      const bool light = ((px / 4) + (py / 4)) % 2 == 0;
      for (int c = 0; c < 3; ++c) {
        const Tally& t = ch[static_cast<size_t>((py * 16 + px) * 3 + c)];
        const double want = light ? 1.0 : dark[c];
        EXPECT_NEAR(t.mean, want, 1e-12 * want) << "pixel " << px << "," << py << " channel " << c;
        EXPECT_EQ(t.n, 16u);
      }
      ++checked;
    }
  }
  EXPECT_EQ(checked, 64);
  // Border pixels blend the two colours: strictly between them in each channel.
  const Tally& border = ch[static_cast<size_t>((0 * 16 + 3) * 3 + 0)];
  EXPECT_GT(border.mean, dark[0]);
  EXPECT_LT(border.mean, 1.0);
  // Two threads: the same bits.
  expect_bit_identical(one, test::run_spec(checker_spec(16), 2, dir.limits()));
}

TEST(Texture, TexturedGltfIsBitIdenticalOnOneAndTwoThreads) {
  TempDir dir("tally_tex_threads");
  std::vector<uint8_t> px;
  for (int i = 0; i < 64; ++i) px.insert(px.end(), {uint8_t(i * 4), uint8_t(255 - i * 3), uint8_t(i * i % 256)});
  const std::string png = encode("v.png", 8, 8, 3, px);
  const std::array<std::string, 3> pngs = {png, png, png};
  write_file(dir.assets() / "t.glb", textured_gltf(Factors{}, true, ImageStore::buffer_view, pngs).glb());
  const test::JobRun one = test::run_spec(gltf_image_spec("t.glb", 16), 1, dir.limits());
  const test::JobRun two = test::run_spec(gltf_image_spec("t.glb", 16), 2, dir.limits());
  expect_bit_identical(one, two);
  // Three images (the same bytes, but three glTF images): decoded once each.
  const Scene s = parse({{"shapes", json::array({{{"type", "gltf"}, {"file", "t.glb"}}})}}, dir.limits());
  EXPECT_EQ(s.textures.size(), 3u);
  EXPECT_EQ(s.texture_bytes, 3u * 64u * 12u);
}

// --- bad inputs ------------------------------------------------------------------------

json gltf_scene(const std::string& file) { return {{"shapes", json::array({{{"type", "gltf"}, {"file", file}}})}}; }

// A quad whose base colour texture is `image` (a glTF image object), with `info` extra
// members in the textureInfo.
void write_bad_gltf(const TempDir& dir, const std::string& name, const json& image, const json& info = json::object(),
                    const json& sampler = json(), bool uvs = true) {
  GltfWriter w;
  w.doc["images"] = {image};
  json t = {{"source", 0}};
  if (!sampler.is_null()) {
    w.doc["samplers"] = {sampler};
    t["sampler"] = 0;
  }
  w.doc["textures"] = {t};
  json ti = {{"index", 0}};
  ti.update(info);
  const int m = w.material({{"pbrMetallicRoughness", {{"baseColorTexture", ti}}}});
  w.node({{"mesh", w.mesh({0, 0, 0, 1, 0, 0, 1, 1, 0}, {0, 1, 2}, m, {}, uvs ? std::vector<float>{0, 0, 1, 0, 1, 1} : std::vector<float>{})}});
  w.save_gltf(dir.assets(), name);
}

TEST(Texture, BadTexturesFailWithErrorsNamingTheField) {
  TempDir dir("tally_tex_bad");
  const JobLimits lim = dir.limits();
  write_file(dir.assets() / "ok.png", constant_png(1, 2, 3));
  write_file(dir.root / "outside" / "secret.png", constant_png(1, 2, 3));
  fs::create_directories(dir.assets() / "dir.png");
  ASSERT_EQ(::mkfifo((dir.assets() / "fifo.png").c_str(), 0600), 0);
  write_file(dir.assets() / "text.png", "not an image at all");
  {
    std::vector<unsigned char> buf;
    OIIO::Filesystem::IOVecOutput proxy(buf);
    auto out = OIIO::ImageOutput::create("x.exr", &proxy);
    OIIO::ImageSpec spec(2, 2, 3, OIIO::TypeDesc::FLOAT);
    const std::vector<float> f(12, 0.5f);
    out->open("x.exr", spec);
    out->write_image(OIIO::TypeDesc::FLOAT, f.data());
    out->close();
    write_file(dir.assets() / "hdr.exr", std::string(buf.begin(), buf.end()));
  }
  const std::string p = "/scene/shapes/0/file: glTF ";
  struct Case {
    std::string name;
    json image, info, sampler;
    bool uvs;
    std::string want;
  };
  const std::vector<Case> cases = {
      {"missing", {{"uri", "nope.png"}}, json::object(), json(), true,
       p + "\"missing.gltf\" /images/0/uri: cannot be read: \"nope.png\": asset \"nope.png\" not found"},
      {"escape", {{"uri", "../outside/secret.png"}}, json::object(), json(), true,
       p + "\"escape.gltf\" /images/0/uri: cannot be read: \"./../outside/secret.png\": must not contain \"..\""},
      {"absolute", {{"uri", (dir.root / "outside" / "secret.png").string()}}, json::object(), json(), true,
       p + "\"absolute.gltf\" /images/0/uri: cannot be read: \"" + (dir.root / "outside" / "secret.png").string() +
           "\": must be a relative path inside the asset directory"},
      {"directory", {{"uri", "dir.png"}}, json::object(), json(), true,
       p + "\"directory.gltf\" /images/0/uri: cannot be read: \"dir.png\": is not a regular file"},
      {"fifo", {{"uri", "fifo.png"}}, json::object(), json(), true,
       p + "\"fifo.gltf\" /images/0/uri: cannot be read: \"fifo.png\": is not a regular file"},
      {"texcoord", {{"uri", "ok.png"}}, {{"texCoord", 1}}, json(), true,
       p + "\"texcoord.gltf\" /materials/0/pbrMetallicRoughness/baseColorTexture/texCoord: only texture coordinate set 0 (TEXCOORD_0) is supported"},
      {"transform", {{"uri", "ok.png"}}, {{"extensions", {{"KHR_texture_transform", {{"scale", {2, 2}}}}}}}, json(), true,
       p + "\"transform.gltf\" /materials/0/pbrMetallicRoughness/baseColorTexture/extensions/KHR_texture_transform: is not supported"},
      {"text", {{"uri", "text.png"}}, json::object(), json(), true,
       p + "\"text.gltf\" /images/0: cannot be used as a texture: is not a PNG or JPEG image"},
      {"exr", {{"uri", "hdr.exr"}}, json::object(), json(), true,
       p + "\"exr.gltf\" /images/0: cannot be used as a texture: openexr textures are not supported (PNG and JPEG are)"},
      {"wrap", {{"uri", "ok.png"}}, json::object(), {{"wrapS", 10497}, {"wrapT", 1234}}, true,
       p + "\"wrap.gltf\" /samplers/0/wrapT: unknown wrap mode 1234 (10497, 33071 or 33648)"},
      {"nouv", {{"uri", "ok.png"}}, json::object(), json(), false,
       p + "\"nouv.gltf\" /meshes/0/primitives/0/attributes: has no TEXCOORD_0, but its material has textures"},
  };
  for (const Case& c : cases) {
    write_bad_gltf(dir, c.name, c.image, c.info, c.sampler, c.uvs);
    EXPECT_EQ(error_of(gltf_scene(c.name + ".gltf"), lim), c.want) << c.name;
  }
  // The decoded-texel budget: 4 x 4 texels are 192 bytes.
  write_bad_gltf(dir, "budget", {{"uri", "ok.png"}});
  JobLimits small = lim;
  small.max_texture_bytes = 191;
  EXPECT_EQ(error_of(gltf_scene("budget.gltf"), small),
            p + "\"budget.gltf\" /images/0: cannot be used as a texture: the image has 4x4 pixels, more than the limit of 15 "
                "(the job's textures may take 191 bytes decoded, 12 a texel)");
  small.max_texture_bytes = 192;
  EXPECT_EQ(error_of(gltf_scene("budget.gltf"), small), "");
  // A point query cannot use a textured material (it has no texture coordinates).
  write_bad_gltf(dir, "named", {{"uri", "ok.png"}});
  json spec = test::point_spec(gltf_scene("named.gltf"), {"mis"}, 4);
  spec["query"]["points"][0]["material"] = "named.gltf#0";
  try {
    compile_lighting_job(spec, lim);
    ADD_FAILURE() << "no error";
  } catch (const SpecError& e) {
    EXPECT_STREQ(e.what(), "/query/points/0/material: has textures; a query point has no texture coordinates");
  }
}

TEST(Texture, BadMtlTexturesFailWithErrorsNamingTheField) {
  TempDir dir("tally_tex_badmtl");
  const JobLimits lim = dir.limits();
  const json scene = {{"shapes", json::array({{{"type", "mesh"}, {"obj", "m/quad.obj"}}})}};
  const std::string p = "/scene/shapes/0/obj: material \"checker\": map_Kd ";
  write_checker_obj(dir, "map_Kd tex/none.png");
  EXPECT_EQ(error_of(scene, lim), p + "\"tex/none.png\": asset \"m/tex/none.png\" not found");
  write_checker_obj(dir, "map_Kd ../../outside/secret.png");
  write_file(dir.root / "outside" / "secret.png", constant_png(1, 2, 3));
  EXPECT_EQ(error_of(scene, lim), p + "\"../../outside/secret.png\": must not contain \"..\"");
  fs::create_directories(dir.assets() / "m" / "d.png");
  write_checker_obj(dir, "map_Kd d.png");
  EXPECT_EQ(error_of(scene, lim), p + "\"d.png\": is not a regular file");
  write_checker_obj(dir, "map_Kd quad.obj");
  EXPECT_EQ(error_of(scene, lim), p + "\"quad.obj\": cannot be used as a texture: is not a PNG or JPEG image");
  write_checker_obj(dir, "map_Kd -s 2 2 1 tex/checker.png");
  EXPECT_EQ(error_of(scene, lim), p + "\"tex/checker.png\": the options -o, -s, -t and -mm are not supported");
  // A face of the textured material without vt.
  write_checker_obj(dir);
  std::ofstream(dir.assets() / "m" / "quad.obj") << "mtllib quad.mtl\nv -1 -1 0\nv 1 -1 0\nv 1 1 0\nvt 0 0\n"
                                                  << "usemtl checker\nf 1/1 2/1 3/1\nf 1 2 3\n";
  EXPECT_EQ(error_of(scene, lim),
            "/scene/shapes/0/obj: material \"m/quad.obj#checker\" has a texture, but face 1 of its faces has no vt");
}

// texture.<backend>_module: the module ctest asked for is the one loaded.
TEST(ImageModule, IsTheOneRequested) { test::expect_the_requested_image_module(); }

}  // namespace
}  // namespace tally
