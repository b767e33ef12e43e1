#pragma once
// Helpers for the environment-light tests: maps written by the test with OpenImageIO
// into a fresh directory (no downloads), the closed forms of a texel's solid angle and
// of its cosine-weighted integral, and point-query specs.
#include <OpenImageIO/imageio.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <numbers>
#include <string>
#include <vector>

#include "common/math/vec3.hpp"
#include "lighting/lighting_test_support.hpp"

namespace tally::test {

namespace fs = std::filesystem;
// A directory of its own per test (tally_envlight_<name>_<pid>/assets is the asset dir).
struct TempDir : AssetSandbox {
  explicit TempDir(const std::string& name) : AssetSandbox("tally_envlight_" + name) {}
};
inline constexpr double kPiT = std::numbers::pi;

// RGB float image, row-major from the top row, written with OpenImageIO (format by the
// extension: .exr float, .hdr RGBE).
inline void write_image(const fs::path& p, int w, int h, const std::vector<float>& rgb) {
  auto out = OIIO::ImageOutput::create(p.string());
  if (!out) throw std::runtime_error("no writer for " + p.string());
  OIIO::ImageSpec spec(w, h, 3, OIIO::TypeDesc::FLOAT);
  if (!out->open(p.string(), spec) || !out->write_image(OIIO::TypeDesc::FLOAT, rgb.data()) || !out->close()) {
    throw std::runtime_error("cannot write " + p.string() + ": " + out->geterror());
  }
}

inline std::vector<float> constant_rgb(int w, int h, float r, float g, float b) {
  std::vector<float> v(3 * static_cast<size_t>(w) * static_cast<size_t>(h));
  for (size_t i = 0; i < v.size(); i += 3) v[i] = r, v[i + 1] = g, v[i + 2] = b;
  return v;
}

// The documented convention (environment_map.hpp), written independently of it:
// d(u, v) = (sin t sin p, cos t, -sin t cos p), t = pi v, p = 2 pi u, then R_y(alpha).
inline Vec3 rotate_y(const Vec3& d, double alpha_deg) {
  const double a = alpha_deg * kPiT / 180.0, c = std::cos(a), s = std::sin(a);
  return {d.x * c + d.z * s, d.y, -d.x * s + d.z * c};
}
inline Vec3 map_direction(double u, double v, double alpha_deg = 0) {
  const double t = kPiT * v, p = 2 * kPiT * u;
  return rotate_y({std::sin(t) * std::sin(p), std::cos(t), -std::sin(t) * std::cos(p)}, alpha_deg);
}

// Solid angle of texel row iv of a W x H map.
inline double texel_solid_angle(int w, int h, int iv) {
  return (2 * kPiT / w) * (std::cos(kPiT * iv / h) - std::cos(kPiT * (iv + 1) / h));
}

// The integral of the direction over texel (iu, iv), rotated: V = ∫ d dω. For a texel
// wholly above the horizon of n, the irradiance it gives with radiance H is H n.V.
inline Vec3 texel_direction_integral(int w, int h, int iu, int iv, double alpha_deg = 0) {
  const double t0 = kPiT * iv / h, t1 = kPiT * (iv + 1) / h;
  const double p0 = 2 * kPiT * iu / w, p1 = 2 * kPiT * (iu + 1) / w;
  const double a = (t1 / 2 - std::sin(2 * t1) / 4) - (t0 / 2 - std::sin(2 * t0) / 4);  // ∫ sin^2
  const double b = (std::sin(t1) * std::sin(t1) - std::sin(t0) * std::sin(t0)) / 2;     // ∫ sin cos
  const Vec3 v{a * (std::cos(p0) - std::cos(p1)), b * (p1 - p0), -a * (std::sin(p1) - std::sin(p0))};
  return rotate_y(v, alpha_deg);
}

// A point query at the origin with normal n, diffuse albedo rho, no shapes.
inline json env_point_spec(const json& sky, const Vec3& n, const std::vector<std::string>& estimators, uint64_t samples,
                           double rho = 0.5, uint64_t seed = 11) {
  return {{"kind", "lighting"},
          {"seed", seed},
          {"scene", {{"lights", json::array({sky})}}},
          {"query", {{"type", "points"},
                     {"points", json::array({{{"p", {0, 0, 0}}, {"n", vec(n)}, {"material", diffuse(rho)}}})}}},
          {"estimators", estimators},
          {"stop", {{"max_samples", samples}}}};
}

}  // namespace tally::test
