#pragma once
// The environment light: an equirectangular (latitude-longitude) map of radiance that
// surrounds the scene at infinity (docs/lighting.md, "Environment light").
//
// Direction convention (right-handed, +y up, the scene's own axes):
//   theta = pi v in [0, pi] is the angle from +y (v = 0, the map's top row, is straight up);
//   phi = 2 pi u in [0, 2 pi) is the azimuth, and the unrotated map's direction is
//     d(u, v) = (sin theta sin phi, cos theta, -sin theta cos phi),
//   so u = 0 (the left edge) looks along -z, u = 1/4 along +x, u = 1/2 along +z and
//   u = 3/4 along -x (Mitsuba 3's convention for a y-up world).
//   rotation_deg alpha turns the map about +y by alpha, right-handed (counter-clockwise
//   seen from above): a feature at d in the unrotated map is seen at R_y(alpha) d,
//   R_y(alpha) (x, y, z) = (x cos a + z sin a, y, -x sin a + z cos a).
// Lookup is nearest-texel: L(w) = intensity * texel(cell of (u, v)). The radiance is
// therefore constant on each texel's cell, exactly the cells of the sampling density.
//
// Sampling: the piecewise-constant 2-D distribution (common/sampling/piecewise_constant)
// over (u, v) in [0, 1]^2 with cell weights luminance(texel) * sin(theta at the cell's
// centre row); the solid-angle density of a direction is pdf_uv / (2 pi^2 sin theta)
// with theta the direction's own polar angle (dw = 2 pi^2 sin theta du dv). sample()
// returns pdf(wi) and radiance(wi) of the direction it made, so the density the
// estimators divide by and the one MIS weighs BSDF samples with are one function.
//
// Immutable after construction: every method is const and touches no mutable state, so
// one map is shared read-only by all threads of a job (and by nothing else).
#include <cstdint>
#include <array>
#include <cstddef>
#include <optional>
#include <span>
#include <vector>

#include "common/lighting/scene.hpp"
#include "common/math/vec3.hpp"
#include "common/sampling/piecewise_constant.hpp"

namespace tally {

// Bytes an environment map takes a texel: its decoded RGB floats (12) and, once built,
// its texels and sampling tables (~70). Charged when a map is decoded (max_decode_bytes)
// and in Scene::resident_bytes.
inline constexpr uint64_t kEnvironmentTexelBytes = 12 + 70;

class EnvironmentMap {
 public:
  struct Sample {
    Vec3 wi{};      // unit world direction towards the environment
    Rgb le{};       // radiance arriving from wi
    double pdf = 0; // solid angle; 0: no sample
  };

  // rgb: 3 * width * height linear values, row-major from the top row (v = 0). Needs
  // width == 2 * height >= 2, every value finite and >= -kNegativeTexelTolerance x the
  // map's largest value, intensity finite and >= 0, rotation_deg finite. Throws
  // std::invalid_argument saying which texel or parameter. Values below 0 but within the
  // tolerance (lossy compression and filtering leave them: every one of Blender's studio
  // world maps has some, down to -0.004) are read as 0 and counted (negative_texels()).
  EnvironmentMap(int width, int height, std::span<const float> rgb, double intensity, double rotation_deg);

  // Texel channels below 0 read as 0, and the most negative of them (0 if none).
  size_t negative_texels() const { return negative_texels_; }
  float most_negative() const { return most_negative_; }
  static constexpr float kNegativeTexelTolerance = 1e-3f;

  int width() const { return width_; }
  int height() const { return height_; }
  // No texel emits (or intensity 0): not a light.
  bool black() const { return !dist_.has_value(); }
  // All texels equal: their radiance (intensity applied), else nullopt.
  std::optional<Rgb> constant() const { return constant_; }
  // (1 / 4 pi) * integral of L over the sphere, per channel (for the light's power).
  Rgb mean_radiance() const { return mean_; }

  Rgb radiance(const Vec3& w) const;
  double pdf(const Vec3& w) const;
  // u: two uniform numbers in [0, 1).
  Sample sample(Vec2 u) const;

  // The map coordinates of a world direction (rotation undone) and back.
  Vec2 to_uv(const Vec3& w) const;
  Vec3 from_uv(Vec2 uv) const;
  // The texel {column, row} that radiance() and pdf() read for w.
  std::array<size_t, 2> texel_of(const Vec3& w) const;
  const Rgb& texel(size_t column, size_t row) const { return texels_[row * static_cast<size_t>(width_) + column]; }

 private:
  std::array<size_t, 2> cell_of_uv(Vec2 uv) const;

  int width_ = 0, height_ = 0;
  double cos_rot_ = 1, sin_rot_ = 0;
  std::vector<Rgb> texels_;  // intensity applied
  std::optional<PiecewiseConstant2D> dist_;
  std::optional<Rgb> constant_;
  Rgb mean_{};
  size_t negative_texels_ = 0;
  float most_negative_ = 0;
};

// The radiance a ray leaving the scene along w finds: the map, the constant sky, or 0.
inline bool has_sky(const Scene& s) { return s.sky.has_value() || s.environment != nullptr; }
inline Rgb sky_radiance(const Scene& s, const Vec3& w) {
  if (s.environment) return s.environment->radiance(w);
  return s.sky ? *s.sky : Rgb{};
}
// A sky that emits something (the planner's and the light set's test).
inline bool sky_emits(const Scene& s) {
  return (s.sky && !is_black(*s.sky)) || (s.environment && !s.environment->black());
}

}  // namespace tally
