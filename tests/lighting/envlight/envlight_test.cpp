// The environment light (issue 16): an equirectangular map as a light, importance-sampled
// and MIS-weighted. Every map is written here with OpenImageIO. Statistical bounds are
// 4 sigma (false-failure rate ~6e-5 per bound) and the chi-square tests are Šidák-
// corrected to a family-wise rate of 0.01 over the two cases, seeds fixed.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <iostream>
#include <limits>

#include "common/image/image_decode.hpp"
#include "common/image/image_io.hpp"
#include "common/lighting/environment_map.hpp"
#include "common/lighting/light_set.hpp"
#include "common/lighting/scene_json.hpp"
#include "common/rng/counter_rng.hpp"
#include "lighting/envlight/envlight_support.hpp"
#include "support/chi_square.hpp"
#include "support/requested_image_module.hpp"

namespace tally::test {
namespace {

// ---------------------------------------------------------------- decoding

TEST(EnvLightDecode, ExrFloatsRoundTripExactly) {
  TempDir dir("decode_exr");
  std::vector<float> rgb(3 * 6 * 3);
  for (size_t i = 0; i < rgb.size(); ++i) rgb[i] = static_cast<float>(0.001 * static_cast<double>(i * i) + 1e-7 * static_cast<double>(i));
  write_image(dir.assets() / "m.exr", 6, 3, rgb);
  std::ifstream f(dir.assets() / "m.exr", std::ios::binary);
  const std::string bytes((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
  EXPECT_EQ(sniff_image_format(bytes), "openexr");
  const DecodedImage im = decode_image(bytes, 1000);
  EXPECT_EQ(im.width, 6);
  EXPECT_EQ(im.height, 3);
  EXPECT_EQ(im.channels, 3);
  EXPECT_EQ(im.bits, 32);
  ASSERT_EQ(im.floats.size(), rgb.size());
  for (size_t i = 0; i < rgb.size(); ++i) EXPECT_EQ(im.floats[i], rgb[i]) << i;  // 32-bit float, bit for bit
  // Over the pixel limit: refused before the pixels are read.
  EXPECT_THROW(decode_image(bytes, 17), std::runtime_error);
  // Not an image; a truncated one.
  EXPECT_THROW(decode_image("P6 not an hdr", 1000), std::runtime_error);
  EXPECT_THROW(decode_image(bytes.substr(0, bytes.size() / 2), 1000), std::runtime_error);
  EXPECT_THROW(decode_image("", 1000), std::runtime_error);
}

TEST(EnvLightDecode, RadianceHdrDecodesWithTheOpenImageIoModule) {
  TempDir dir("decode_hdr");
  const std::vector<float> rgb = {0.5f, 1.0f, 2.0f, 3.0f, 0.25f, 0.125f, 0, 0, 0, 10, 20, 40};
  write_image(dir.assets() / "m.hdr", 2, 2, rgb);
  std::ifstream f(dir.assets() / "m.hdr", std::ios::binary);
  const std::string bytes((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
  EXPECT_EQ(sniff_image_format(bytes), "hdr");
  if (image_module_backend().rfind("OpenImageIO", 0) != 0) {
    try {
      decode_image(bytes, 100);
      FAIL() << "the OpenEXR module decoded an .hdr";
    } catch (const std::runtime_error& e) {
      EXPECT_NE(std::string(e.what()).find("decodes PNG and OpenEXR only, not hdr"), std::string::npos) << e.what();
    }
    return;
  }
  const DecodedImage im = decode_image(bytes, 100);
  ASSERT_EQ(im.width, 2);
  ASSERT_EQ(im.height, 2);
  ASSERT_EQ(im.channels, 3);
  ASSERT_EQ(im.floats.size(), 12u);
  // RGBE keeps 8 mantissa bits per pixel's largest channel: within 1/128 of that channel.
  for (size_t p = 0; p < 4; ++p) {
    const float peak = std::max({rgb[3 * p], rgb[3 * p + 1], rgb[3 * p + 2]});
    for (size_t c = 0; c < 3; ++c) EXPECT_NEAR(im.floats[3 * p + c], rgb[3 * p + c], static_cast<double>(peak) / 128.0) << p << " " << c;
  }
}

// ---------------------------------------------------------------- the map itself

// A 32 x 16 map with two black rows at the top (zero density there), a hot 2x2 block and
// a ragged background.
std::vector<float> test_map_rgb(int w = 32, int h = 16) {
  std::vector<float> v(3 * static_cast<size_t>(w) * static_cast<size_t>(h));
  for (int iv = 0; iv < h; ++iv) {
    for (int iu = 0; iu < w; ++iu) {
      float r = 0, g = 0, b = 0;
      if (iv >= 2) {
        const float base = 0.2f + 0.1f * static_cast<float>((iu * 7 + iv * 3) % 5);
        r = base, g = 0.5f * base, b = base + 0.05f * static_cast<float>(iu % 3);
      }
      if ((iu == 20 || iu == 21) && (iv == 5 || iv == 6)) r = 40, g = 30, b = 20;
      const size_t i = 3 * (static_cast<size_t>(iv) * static_cast<size_t>(w) + static_cast<size_t>(iu));
      v[i] = r, v[i + 1] = g, v[i + 2] = b;
    }
  }
  return v;
}

// (u, v) of a world direction under the documented convention, computed here.
Vec2 independent_uv(const Vec3& w, double alpha_deg) {
  const Vec3 d = rotate_y(w, -alpha_deg);
  double phi = std::atan2(d.x, -d.z);
  if (phi < 0) phi += 2 * kPiT;
  return {phi / (2 * kPiT), std::acos(std::clamp(d.y, -1.0, 1.0)) / kPiT};
}

TEST(EnvMap, DirectionConvention) {
  const EnvironmentMap env(8, 4, constant_rgb(8, 4, 1, 1, 1), 1.0, 0.0);
  auto near = [](const Vec3& a, const Vec3& b) { return length(a - b) < 1e-12; };
  EXPECT_TRUE(near(env.from_uv({0.0, 0.5}), {0, 0, -1}));   // u = 0: -z
  EXPECT_TRUE(near(env.from_uv({0.25, 0.5}), {1, 0, 0}));   // u = 1/4: +x
  EXPECT_TRUE(near(env.from_uv({0.5, 0.5}), {0, 0, 1}));    // u = 1/2: +z
  EXPECT_TRUE(near(env.from_uv({0.75, 0.5}), {-1, 0, 0}));  // u = 3/4: -x
  EXPECT_TRUE(near(env.from_uv({0.3, 0.0}), {0, 1, 0}));    // v = 0: +y (up)
  // Rotated by 90 degrees about +y (right-handed): -z turns to -x.
  const EnvironmentMap rot(8, 4, constant_rgb(8, 4, 1, 1, 1), 1.0, 90.0);
  EXPECT_TRUE(near(rot.from_uv({0.0, 0.5}), {-1, 0, 0}));
  for (double a : {0.0, 90.0, 37.0, -123.5}) {
    const EnvironmentMap e(8, 4, constant_rgb(8, 4, 1, 1, 1), 1.0, a);
    for (const Vec2 uv : {Vec2{0.1, 0.2}, Vec2{0.6, 0.7}, Vec2{0.93, 0.51}}) {
      EXPECT_LT(length(e.from_uv(uv) - map_direction(uv.x, uv.y, a)), 1e-12) << a;
      const Vec2 back = e.to_uv(map_direction(uv.x, uv.y, a));
      EXPECT_NEAR(back.x, uv.x, 1e-12);
      EXPECT_NEAR(back.y, uv.y, 1e-12);
    }
  }
}

TEST(EnvMap, SampledPdfEqualsPdfOfTheDirectionAndTheClosedForm) {
  const int W = 32, H = 16;
  const std::vector<float> rgb = test_map_rgb(W, H);
  for (double alpha : {0.0, 30.0}) {
    const double intensity = 1.7;
    const EnvironmentMap env(W, H, rgb, intensity, alpha);
    // The density written out from the documentation: cell weight luminance * sin(theta_c).
    double total = 0;
    for (int iv = 0; iv < H; ++iv) {
      for (int iu = 0; iu < W; ++iu) {
        const size_t i = 3 * static_cast<size_t>(iv * W + iu);
        const Rgb t = Rgb{rgb[i], rgb[i + 1], rgb[i + 2]} * intensity;
        total += luminance(t) * std::sin(kPiT * (iv + 0.5) / H) / (W * H);
      }
    }
    int checked = 0;
    for (uint64_t k = 0; k < 20000; ++k) {
      const SampleRng rng(3, k);
      const EnvironmentMap::Sample s = env.sample({rng.uniform(0), rng.uniform(1)});
      ASSERT_GT(s.pdf, 0);
      EXPECT_EQ(s.pdf, env.pdf(s.wi));  // the same function, bit for bit
      const Vec2 uv = independent_uv(s.wi, alpha);
      const int iu = std::min(static_cast<int>(uv.x * W), W - 1), iv = std::min(static_cast<int>(uv.y * H), H - 1);
      const auto cell = env.texel_of(s.wi);
      ASSERT_EQ(cell[0], static_cast<size_t>(iu));
      ASSERT_EQ(cell[1], static_cast<size_t>(iv));
      const size_t i = 3 * static_cast<size_t>(iv * W + iu);
      const Rgb t = Rgb{rgb[i], rgb[i + 1], rgb[i + 2]} * intensity;
      ASSERT_GE(iv, 2) << "sampled a black row";
      const double pdf_uv = luminance(t) * std::sin(kPiT * (iv + 0.5) / H) / total;
      const double sin_theta = std::sin(kPiT * uv.y);
      EXPECT_NEAR(s.pdf, pdf_uv / (2 * kPiT * kPiT * sin_theta), 1e-9 * s.pdf);
      EXPECT_EQ(s.le.x, t.x);  // nearest texel, intensity applied
      EXPECT_EQ(s.le.y, t.y);
      EXPECT_EQ(s.le.z, t.z);
      ++checked;
    }
    EXPECT_EQ(checked, 20000);
    // A direction in a black row has density 0 (never sampled) and radiance 0.
    const Vec3 up = map_direction(0.4, 0.05, alpha);
    EXPECT_EQ(env.pdf(up), 0.0);
    EXPECT_TRUE(is_black(env.radiance(up)));
    // The light set hands the same density to MIS (with the choice of light).
    Scene scene;
    scene.environment = std::make_shared<const EnvironmentMap>(env);
    const LightSet lights(scene);
    EXPECT_EQ(lights.pick_pmf_sky(), 1.0);
    for (uint64_t k = 0; k < 1000; ++k) {
      const SampleRng rng(4, k);
      const LightSample ls = lights.sample({0, 0, 0}, {0, 0, 1}, rng.uniform(0), rng.uniform(1), rng.uniform(2));
      ASSERT_TRUE(ls.sky);
      EXPECT_EQ(ls.pdf, lights.pdf_sky({0, 0, 1}, ls.wi));
      EXPECT_EQ(ls.pdf, env.pdf(ls.wi));
    }
  }
}

TEST(EnvMap, ChiSquareOfSampledDirectionsAgainstThePdf) {
  // Directions binned into 2x2 sub-cells of every texel by the convention computed here
  // (not by the map's own lookup); the expected count of a bin is N times the integral
  // of pdf(w) dw over it, dw = 2 pi^2 sin(theta) du dv (8x8 midpoint rule; pdf(w) sin(theta)
  // is constant on a texel, so the rule is exact up to rounding).
  const int W = 32, H = 16, B = 2;
  const std::vector<float> rgb = test_map_rgb(W, H);
  const double level = sidak_level(0.01, 2);
  for (double alpha : {0.0, 30.0}) {
    const EnvironmentMap env(W, H, rgb, 1.0, alpha);
    const int bu = W * B, bv = H * B;
    std::vector<double> obs(static_cast<size_t>(bu * bv), 0), expct(obs.size(), 0);
    const uint64_t N = 2000000;
    for (uint64_t k = 0; k < N; ++k) {
      const SampleRng rng(17 + static_cast<uint64_t>(alpha), k);  // independent cases
      const EnvironmentMap::Sample s = env.sample({rng.uniform(0), rng.uniform(1)});
      ASSERT_GT(s.pdf, 0);
      const Vec2 uv = independent_uv(s.wi, alpha);
      const int i = std::min(static_cast<int>(uv.x * bu), bu - 1), j = std::min(static_cast<int>(uv.y * bv), bv - 1);
      obs[static_cast<size_t>(j * bu + i)] += 1;
    }
    const int S = 8;
    double total = 0, in_zero_bins = 0;
    for (int j = 0; j < bv; ++j) {
      for (int i = 0; i < bu; ++i) {
        double p = 0;
        for (int a = 0; a < S; ++a) {
          for (int b = 0; b < S; ++b) {
            const double u = (i + (a + 0.5) / S) / bu, v = (j + (b + 0.5) / S) / bv;
            p += env.pdf(map_direction(u, v, alpha)) * 2 * kPiT * kPiT * std::sin(kPiT * v) / (bu * bv * S * S);
          }
        }
        expct[static_cast<size_t>(j * bu + i)] = p * static_cast<double>(N);
        total += p;
        if (p == 0) in_zero_bins += obs[static_cast<size_t>(j * bu + i)];
      }
    }
    EXPECT_NEAR(total, 1.0, 1e-9) << "the pdf integrates to 1 over the sphere";
    EXPECT_EQ(in_zero_bins, 0) << "a direction was sampled where the pdf is 0";
    const double p = chi_square_p(obs, expct);
    std::cout << "[ figures  ] rotation " << alpha << ": chi-square p = " << p << " (level " << level << ")\n";
    EXPECT_GT(p, level) << "rotation " << alpha;
  }
}

TEST(EnvMap, RotationMovesTheHotTexelByRy) {
  // One hot texel; with rotation_deg alpha its radiance is found at R_y(alpha) d(texel centre).
  const int W = 64, H = 32, iu = 40, iv = 11;
  std::vector<float> rgb = constant_rgb(W, H, 0, 0, 0);
  const size_t i = 3 * static_cast<size_t>(iv * W + iu);
  rgb[i] = rgb[i + 1] = rgb[i + 2] = 100;
  const Vec2 centre{(iu + 0.5) / W, (iv + 0.5) / H};
  for (double alpha : {0.0, 37.0, -90.0, 200.0}) {
    const EnvironmentMap env(W, H, rgb, 1.0, alpha);
    const Vec3 hot = rotate_y(map_direction(centre.x, centre.y), alpha);
    EXPECT_EQ(env.radiance(hot).x, 100.0) << alpha;
    EXPECT_GT(env.pdf(hot), 0) << alpha;
    // Every sample is in that texel: within its half-diagonal of the centre direction.
    for (uint64_t k = 0; k < 200; ++k) {
      const SampleRng rng(5, k);
      const EnvironmentMap::Sample s = env.sample({rng.uniform(0), rng.uniform(1)});
      EXPECT_LT(std::acos(std::clamp(dot(s.wi, hot), -1.0, 1.0)), kPiT / H) << alpha;
    }
    if (alpha != 0) {
      const Vec3 unrotated = map_direction(centre.x, centre.y);
      EXPECT_EQ(env.radiance(unrotated).x, 0.0) << alpha;
    }
  }
}

TEST(EnvMap, BadMapsAreRefusedNamingTheTexel) {
  auto message = [](int w, int h, std::vector<float> rgb, double intensity = 1, double rot = 0) {
    try {
      (void)EnvironmentMap(w, h, rgb, intensity, rot);
    } catch (const std::invalid_argument& e) {
      return std::string(e.what());
    }
    return std::string("<accepted>");
  };
  std::vector<float> m = constant_rgb(8, 4, 1, 1, 1);
  m[3 * (2 * 8 + 5) + 1] = std::numeric_limits<float>::quiet_NaN();
  EXPECT_NE(message(8, 4, m).find("texel (column 5, row 2) channel G is nan"), std::string::npos) << message(8, 4, m);
  m = constant_rgb(8, 4, 1, 1, 1);
  m[3 * 9 + 2] = -0.5f;
  EXPECT_NE(message(8, 4, m).find("texel (column 1, row 1) channel B is -0.5"), std::string::npos) << message(8, 4, m);
  // Just below the tolerance (1e-3 x the largest value, here 1) is still refused.
  m[3 * 9 + 2] = -1.01e-3f;
  EXPECT_NE(message(8, 4, m).find("channel B is -0.00101"), std::string::npos) << message(8, 4, m);
  m[3 * 9 + 2] = std::numeric_limits<float>::infinity();
  EXPECT_NE(message(8, 4, m).find("must be finite"), std::string::npos);
  EXPECT_NE(message(6, 4, constant_rgb(6, 4, 1, 1, 1)).find("2:1"), std::string::npos);
  EXPECT_NE(message(0, 0, {}).find("2:1"), std::string::npos);
  EXPECT_NE(message(8, 4, constant_rgb(8, 4, 1, 1, 1), std::nan("")).find("intensity"), std::string::npos);
  // The largest float times the largest intensity the spec allows (1e12) is still finite.
  const EnvironmentMap big(8, 4, constant_rgb(8, 4, 3.4e38f, 1, 1), 1e12, 0);
  EXPECT_TRUE(std::isfinite(big.mean_radiance().x));
  // Black (or intensity 0) is accepted and is no light.
  EXPECT_TRUE(EnvironmentMap(8, 4, constant_rgb(8, 4, 0, 0, 0), 1, 0).black());
  EXPECT_TRUE(EnvironmentMap(8, 4, constant_rgb(8, 4, 1, 2, 3), 0, 0).black());
}

// ---------------------------------------------------------------- through the job

json sky_map(const std::string& file, double intensity = 1.0, double rotation = 0.0) {
  json j = {{"type", "sky"}, {"map", file}};
  if (intensity != 1.0) j["intensity"] = intensity;
  if (rotation != 0.0) j["rotation_deg"] = rotation;
  return j;
}

// An open scene (a floor and a sphere under the sky) seen by a camera.
json open_image_spec(const json& sky, int spp = 8) {
  return {{"kind", "lighting"},
          {"seed", 9},
          {"scene",
           {{"camera", {{"position", {0, 1.2, 4}}, {"look_at", {0, 0.5, 0}}, {"fov_deg", 50}, {"resolution", {24, 16}}}},
            {"materials", {{"floor", diffuse(0.6)}, {"ball", {{"type", "ggx"}, {"reflectance", {0.9, 0.8, 0.5}}, {"roughness", 0.3}}}}},
            {"shapes", json::array({{{"type", "quad"}, {"corner", {-3, 0, 3}}, {"edge_u", {6, 0, 0}}, {"edge_v", {0, 0, -6}}, {"material", "floor"}},
                                    {{"type", "sphere"}, {"center", {0, 0.6, 0}}, {"radius", 0.6}, {"material", "ball"}}})},
            {"lights", json::array({sky})}}},
          {"query", {{"type", "image"}, {"max_depth", 3}, {"tile_size", 8}}},
          {"estimators", {"mis"}},
          {"stop", {{"max_samples", spp}}}};
}

TEST(EnvLight, ConstantMapIsTheConstantSkyBitForBit) {
  // A constant map is the constant sky of its radiance (the parser makes it one), so the
  // image, the point estimates and the counters are the same bits.
  TempDir dir("constant");
  write_image(dir.assets() / "c.exr", 16, 8, constant_rgb(16, 8, 0.5f, 0.25f, 1.0f));
  const json map = sky_map("c.exr", 2.0, 33.0);  // rotation of a constant map changes nothing
  const json sky = {{"type", "sky"}, {"radiance", {1.0, 0.5, 2.0}}};
  const JobRun a = run_spec(open_image_spec(map), 2, dir.limits());
  const JobRun b = run_spec(open_image_spec(sky), 2, dir.limits());
  EXPECT_EQ(test::differing_channels(a, b), 0u);
  EXPECT_TRUE(a.runner->state().counters == b.runner->state().counters);
  EXPECT_GT(a.counter(LightingCounter::sky_lookups), 0u);
  const JobRun pa = run_spec(env_point_spec(map, {0, 0, 1}, {"mis", "light_area", "cosine_hemisphere"}, 2000), 1, dir.limits());
  const JobRun pb = run_spec(env_point_spec(sky, {0, 0, 1}, {"mis", "light_area", "cosine_hemisphere"}, 2000), 1, dir.limits());
  EXPECT_EQ(test::differing_channels(pa, pb), 0u);
  EXPECT_NEAR(pa.channel(0).mean, 0.5 * 1.0, 1e-12);  // rho L, red
}

TEST(EnvLight, NearlyConstantMapSampledAsAMapMatchesTheSkyWithinErrorBars) {
  // The same constant with one texel one float step brighter is not short-circuited: it
  // goes through the map's importance sampler (variance > 0, where the sky's cosine
  // sampling has none) and must still give rho L (the step changes it by < 1e-9).
  TempDir dir("nearly");
  const int W = 64, H = 32;
  std::vector<float> rgb = constant_rgb(W, H, 1.5f, 1.5f, 1.5f);
  rgb[3 * (10 * W + 7)] = std::nextafter(1.5f, 2.0f);
  write_image(dir.assets() / "n.exr", W, H, rgb);
  const double rho = 0.6, L = 1.5;
  const JobRun r = run_spec(env_point_spec(sky_map("n.exr"), normalize(Vec3{0.3, 0.5, 0.8}), {"light_area", "mis"}, 100000, rho),
                            1, dir.limits());
  for (size_t e = 0; e < 2; ++e) {
    const Tally& t = r.channel(3 * e);
    EXPECT_GT(t.std_error(), 1e-4) << "the map's sampler ran, not the sky's";
    EXPECT_NEAR(t.mean, rho * L, 4 * t.std_error()) << "estimator " << e;
  }
}

struct HotTexel {
  int W = 128, H = 64, iu = 70, iv = 20;
  double value = 5000;
};

json hot_texel_map(const TempDir& dir, const HotTexel& h, const std::string& name) {
  std::vector<float> rgb = constant_rgb(h.W, h.H, 0, 0, 0);
  const size_t i = 3 * static_cast<size_t>(h.iv * h.W + h.iu);
  rgb[i] = static_cast<float>(h.value), rgb[i + 1] = static_cast<float>(0.5 * h.value), rgb[i + 2] = static_cast<float>(0.25 * h.value);
  write_image(dir.assets() / name, h.W, h.H, rgb);
  return name;
}

TEST(EnvLight, HotTexelMatchesItsClosedFormAndADirectionalLightOfTheSamePower) {
  // One hot texel of radiance H: irradiance E = H n.V with V = ∫_texel w dw (closed form,
  // envlight_support.hpp); a directional light of irradiance H Omega_texel along the
  // texel's centre gives H Omega n.d_c, which differs from E by the texel's angular extent
  // (second order, printed). Both are compared at 4 sigma of each estimator (mis,
  // light_area: the map's sampler; cosine_hemisphere: the BSDF alone finding the texel).
  TempDir dir("hot");
  const HotTexel h;
  const std::string file = hot_texel_map(dir, h, "hot.exr");
  const double rho = 0.7;
  for (double alpha : {0.0, 37.0}) {
    const Vec3 dc = map_direction((h.iu + 0.5) / h.W, (h.iv + 0.5) / h.H, alpha);
    const Vec3 n = normalize(dc + Vec3{0.2, 0.4, -0.3});  // the texel well above the horizon
    const Vec3 V = texel_direction_integral(h.W, h.H, h.iu, h.iv, alpha);
    const double omega = texel_solid_angle(h.W, h.H, h.iv);
    for (double cu : {0.0, 1.0}) {
      for (double cv : {0.0, 1.0}) {
        ASSERT_GT(dot(n, map_direction((h.iu + cu) / h.W, (h.iv + cv) / h.H, alpha)), 0.3);
      }
    }
    const double closed = rho / kPiT * h.value * dot(n, V);
    const double directional = rho / kPiT * h.value * omega * dot(n, dc);
    // The gap is the texel's finite extent (second order in its 2.8 degrees).
    EXPECT_LT(std::fabs(closed - directional), 1e-3 * closed);
    const JobRun r = run_spec(env_point_spec(sky_map(file, 1.0, alpha), n, {"mis", "light_area", "cosine_hemisphere"}, 200000, rho),
                              1, dir.limits());
    json dl = {{"type", "directional"}, {"direction", vec(dc)}, {"irradiance", {h.value * omega, 0.5 * h.value * omega, 0.25 * h.value * omega}}};
    const JobRun d = run_spec(env_point_spec(dl, n, {"mis"}, 10, rho), 1, dir.limits());
    EXPECT_NEAR(d.channel(0).mean, directional, 1e-12 * directional);
    for (size_t e = 0; e < 3; ++e) {
      const Tally& t = r.channel(3 * e);
      const double se = t.std_error();
      std::cout << "[ figures  ] rotation " << alpha << " estimator " << e << ": " << t.mean << " +- " << se << ", closed form "
                << closed << " (" << (t.mean - closed) / se << " se), directional " << directional << " ("
                << (t.mean - directional) / se << " se)\n";
      EXPECT_GT(se, 0);
      EXPECT_NEAR(t.mean, closed, 4 * se) << "estimator " << e << " rotation " << alpha;
      EXPECT_NEAR(t.mean, d.channel(0).mean, 4 * se + std::fabs(closed - directional))
          << "estimator " << e << " rotation " << alpha << "; |closed - directional| = " << std::fabs(closed - directional)
          << " = " << std::fabs(closed - directional) / se << " se";
      // Green and blue are the same samples at 1/2 and 1/4.
      EXPECT_NEAR(r.channel(3 * e + 1).mean, 0.5 * t.mean, 1e-12 * t.mean);
    }
    // The map's sampler beats the BSDF alone by far on a hot texel.
    EXPECT_LT(r.channel(0).std_error() * 10, r.channel(6).std_error());
    if (alpha != 0) {
      // The unrotated texel direction is dark: a rotated map lights another direction.
      const Vec3 n0 = normalize(map_direction((h.iu + 0.5) / h.W, (h.iv + 0.5) / h.H) + Vec3{0.2, 0.4, -0.3});
      const double closed0 = rho / kPiT * h.value * dot(n0, texel_direction_integral(h.W, h.H, h.iu, h.iv));
      EXPECT_GT(std::fabs(r.channel(0).mean - closed0), 20 * r.channel(0).std_error());
    }
  }
}

TEST(EnvLight, ErrorBarsCoverTheExactValue) {
  // 1000 seeds x 400 samples of a point lit by the ragged test map (normal +y, so the
  // horizon is the equator, a row boundary, and E is a closed form per texel row). The
  // fraction of 95 % intervals holding the exact value must lie in 0.95 +- 4 sd of a
  // binomial(1000, 0.95) fraction: [0.922, 0.978].
  TempDir dir("coverage");
  const int W = 32, H = 16;
  const std::vector<float> rgb = test_map_rgb(W, H);
  write_image(dir.assets() / "m.exr", W, H, rgb);
  const double rho = 0.8;
  double E = 0;
  for (int iv = 0; iv < H / 2; ++iv) {
    const double t0 = kPiT * iv / H, t1 = kPiT * (iv + 1) / H;
    const double w = (2 * kPiT / W) * (std::sin(t1) * std::sin(t1) - std::sin(t0) * std::sin(t0)) / 2;
    for (int iu = 0; iu < W; ++iu) E += static_cast<double>(rgb[3 * static_cast<size_t>(iv * W + iu)]) * w;
  }
  const double exact = rho / kPiT * E;
  int covered = 0;
  const int seeds = 1000;
  for (int s = 0; s < seeds; ++s) {
    const JobRun r = run_spec(env_point_spec(sky_map("m.exr", 1.0, 75.0), {0, 1, 0}, {"mis"}, 400, rho, 5000 + static_cast<uint64_t>(s)),
                              1, dir.limits());
    const Estimate e = r.runner->estimate(0);
    covered += e.ci_lo <= exact && exact <= e.ci_hi ? 1 : 0;
  }
  const double frac = static_cast<double>(covered) / seeds;
  std::cout << "[ figures  ] coverage of the 95 % interval: " << frac << "\n";
  EXPECT_GE(frac, 0.922);
  EXPECT_LE(frac, 0.978);
}

TEST(EnvLight, BitIdenticalForAnyThreadCountAndPlanned) {
  TempDir dir("threads");
  write_image(dir.assets() / "m.exr", 32, 16, test_map_rgb(32, 16));
  for (const char* sampler : {"independent", "sobol"}) {
    json spec = open_image_spec(sky_map("m.exr", 0.8, -20.0), 6);
    spec["sampler"] = sampler;
    const JobRun a = run_spec(spec, 1, dir.limits());
    const JobRun b = run_spec(spec, 2, dir.limits());
    const JobRun c = run_spec(spec, 3, dir.limits());
    EXPECT_EQ(test::differing_channels(a, b), 0u) << sampler;
    EXPECT_EQ(test::differing_channels(a, c), 0u) << sampler;
    EXPECT_TRUE(a.runner->state().counters == c.runner->state().counters) << sampler;
    EXPECT_GT(a.counter(LightingCounter::sky_lookups), 0u);
  }
  // The plan names the environment map as the reason the sky is on.
  const auto job = compile_lighting_job(open_image_spec(sky_map("m.exr")), dir.limits());
  const json plan = plan_json(*job);
  EXPECT_NE(plan.dump().find("environment map (32x16, importance-sampled"), std::string::npos) << plan.dump();
}

// Slightly negative texels (lossy compression leaves them; Blender's studio world maps
// all have some) are read as 0 and counted, and the plan says so: the image is bit for bit
// that of the same map with 0 there.
TEST(EnvLight, SlightlyNegativeTexelsReadAsZeroAndThePlanSaysSo) {
  TempDir dir("negative");
  std::vector<float> m = test_map_rgb(32, 16);
  float largest = 0;
  for (float f : m) largest = std::max(largest, f);
  std::vector<float> zeroed = m;
  m[3 * (5 * 32 + 7) + 0] = -0.5e-3f * largest;
  m[3 * (9 * 32 + 20) + 2] = -0.25e-3f * largest;
  zeroed[3 * (5 * 32 + 7) + 0] = 0.0f;
  zeroed[3 * (9 * 32 + 20) + 2] = 0.0f;
  const EnvironmentMap direct(32, 16, m, 1.0, 0.0);
  EXPECT_EQ(direct.negative_texels(), 2u);
  EXPECT_EQ(direct.most_negative(), -0.5e-3f * largest);
  EXPECT_EQ(direct.texel(7, 5).x, 0.0);
  write_image(dir.assets() / "neg.exr", 32, 16, m);
  write_image(dir.assets() / "zero.exr", 32, 16, zeroed);
  const JobRun a = run_spec(open_image_spec(sky_map("neg.exr"), 4), 2, dir.limits());
  const JobRun b = run_spec(open_image_spec(sky_map("zero.exr"), 4), 2, dir.limits());
  EXPECT_EQ(test::differing_channels(a, b), 0u);
  const json plan = plan_json(*compile_lighting_job(open_image_spec(sky_map("neg.exr")), dir.limits()));
  EXPECT_NE(plan.dump().find("; 2 slightly negative texel values (down to -"), std::string::npos) << plan.dump();
  const json clean = plan_json(*compile_lighting_job(open_image_spec(sky_map("zero.exr")), dir.limits()));
  EXPECT_EQ(clean.dump().find("negative"), std::string::npos) << clean.dump();
}

std::string error_of(const json& spec, const JobLimits& limits, std::string* message = nullptr) {
  try {
    compile_lighting_job(spec, limits);
  } catch (const SpecError& e) {
    if (message) *message = e.what();
    return e.pointer();
  }
  return "<no error>";
}

TEST(EnvLight, BadInputsNameTheField) {
  TempDir dir("bad");
  const JobLimits lim = dir.limits();
  auto spec = [](json sky) { return env_point_spec(sky, {0, 0, 1}, {"mis"}, 10); };
  const std::string map_ptr = "/scene/lights/0/map";
  std::string msg;
  // Missing file; missing stored asset.
  EXPECT_EQ(error_of(spec(sky_map("absent.exr")), lim, &msg), map_ptr) << msg;
  EXPECT_EQ(error_of(spec(sky_map("sha256:" + std::string(64, 'a'))), lim, &msg), map_ptr) << msg;
  // Non-finite and negative texels: named by column, row and channel.
  std::vector<float> m = constant_rgb(16, 8, 1, 1, 1);
  m[3 * (3 * 16 + 4) + 1] = std::numeric_limits<float>::quiet_NaN();
  write_image(dir.assets() / "nan.exr", 16, 8, m);
  EXPECT_EQ(error_of(spec(sky_map("nan.exr")), lim, &msg), map_ptr);
  EXPECT_NE(msg.find("texel (column 4, row 3) channel G is nan"), std::string::npos) << msg;
  m = constant_rgb(16, 8, 1, 1, 1);
  m[3 * 5] = -2.0f;
  write_image(dir.assets() / "neg.exr", 16, 8, m);
  EXPECT_EQ(error_of(spec(sky_map("neg.exr")), lim, &msg), map_ptr);
  EXPECT_NE(msg.find("texel (column 5, row 0) channel R is -2"), std::string::npos) << msg;
  // Zero bytes; not an HDR image; not 2:1.
  std::ofstream(dir.assets() / "empty.exr").close();
  EXPECT_EQ(error_of(spec(sky_map("empty.exr")), lim, &msg), map_ptr);
  EXPECT_NE(msg.find("not an OpenEXR or Radiance"), std::string::npos) << msg;
  std::ofstream(dir.assets() / "text.exr") << "hello";
  EXPECT_EQ(error_of(spec(sky_map("text.exr")), lim, &msg), map_ptr) << msg;
  write_image(dir.assets() / "ldr.png", 8, 4, constant_rgb(8, 4, 0.5f, 0.5f, 0.5f));  // 8-bit: not radiance
  EXPECT_EQ(error_of(spec(sky_map("ldr.png")), lim, &msg), map_ptr);
  EXPECT_NE(msg.find("not an OpenEXR or Radiance .hdr image, a png file"), std::string::npos) << msg;
  std::string exr_bytes;
  write_image(dir.assets() / "cut_src.exr", 16, 8, constant_rgb(16, 8, 1, 2, 3));
  {
    std::ifstream f(dir.assets() / "cut_src.exr", std::ios::binary);
    exr_bytes.assign((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
  }
  std::ofstream(dir.assets() / "cut.exr", std::ios::binary) << exr_bytes.substr(0, exr_bytes.size() / 2);
  EXPECT_EQ(error_of(spec(sky_map("cut.exr")), lim, &msg), map_ptr) << msg;  // truncated: the decoder's error
  write_image(dir.assets() / "square.exr", 8, 8, constant_rgb(8, 8, 1, 1, 1));
  EXPECT_EQ(error_of(spec(sky_map("square.exr")), lim, &msg), map_ptr);
  EXPECT_NE(msg.find("2:1"), std::string::npos) << msg;
  // Parameters.
  write_image(dir.assets() / "ok.exr", 8, 4, test_map_rgb(8, 4));
  json s = spec(sky_map("ok.exr"));
  s["scene"]["lights"][0]["intensity"] = std::nan("");
  EXPECT_EQ(error_of(s, lim, &msg), "/scene/lights/0/intensity") << msg;
  s["scene"]["lights"][0]["intensity"] = -1;
  EXPECT_EQ(error_of(s, lim), "/scene/lights/0/intensity");
  s["scene"]["lights"][0]["intensity"] = "2";
  EXPECT_EQ(error_of(s, lim), "/scene/lights/0/intensity");
  s = spec(sky_map("ok.exr"));
  s["scene"]["lights"][0]["rotation_deg"] = 720;  // outside [-360, 360]
  EXPECT_EQ(error_of(s, lim), "/scene/lights/0/rotation_deg");
  s = spec(sky_map("ok.exr"));
  s["scene"]["lights"][0]["radiance"] = {1, 1, 1};
  EXPECT_EQ(error_of(s, lim), "/scene/lights/0/radiance");
  s = spec({{"type", "sky"}, {"radiance", {1, 1, 1}}, {"rotation_deg", 10}});
  EXPECT_EQ(error_of(s, lim), "/scene/lights/0/rotation_deg");
  s = spec(sky_map("ok.exr"));
  s["scene"]["lights"].push_back({{"type", "sky"}, {"radiance", {1, 1, 1}}});
  EXPECT_EQ(error_of(s, lim), "/scene/lights/1");
  s = spec(sky_map("../escape.exr"));
  EXPECT_EQ(error_of(s, lim), map_ptr);
  // A good map compiles.
  EXPECT_EQ(error_of(spec(sky_map("ok.exr", 2.0, 45.0)), lim), "<no error>");
}

// envlight.<backend>_module: the module ctest asked for is the one loaded.
TEST(ImageModule, IsTheOneRequested) { test::expect_the_requested_image_module(); }

}  // namespace
}  // namespace tally::test
