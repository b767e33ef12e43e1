#pragma once
// The reflection models: Lambertian (diffuse, and the reflective part of emissive
// materials), a perfect mirror (a delta distribution) and normalised Phong,
//   f = k_s (e + 2) / (2 pi) cos^e(alpha),  alpha = angle(w_i, mirror(w_o)),
// whose albedo is <= k_s. Directions are in world space; `n` is the unit normal on
// the side of w_o. Every routine returns 0 (never NaN/Inf) below the horizon.
#include <cmath>

#include "common/lighting/scene.hpp"
#include "common/sampling/safe_math.hpp"
#include "common/sampling/sphere.hpp"

namespace tally {

enum class Strategy { uniform_hemisphere, cosine_hemisphere, light_area, mis };

inline Vec3 reflect(const Vec3& wo, const Vec3& n) { return n * (2.0 * dot(n, wo)) - wo; }

// f_r(w_i -> w_o) for non-delta materials (mirror: 0).
inline Rgb bsdf_eval(const Material& m, const Vec3& n, const Vec3& wo, const Vec3& wi) {
  if (dot(n, wi) <= 0) return {};
  switch (m.type) {
    case MaterialType::diffuse:
    case MaterialType::emissive: return m.albedo * kInvPi;
    case MaterialType::phong: {
      const double c = dot(reflect(wo, n), wi);
      if (c <= 0) return {};
      return m.reflectance * ((m.exponent + 2.0) * kInv2Pi * std::pow(c, m.exponent));
    }
    case MaterialType::mirror: return {};
  }
  return {};
}

struct DirectionSample {
  Vec3 wi{};
  double pdf = 0.0;  // solid angle; 0: no sample (weight 0)
  bool delta = false;
  Rgb weight{};      // f cos / pdf (delta: the reflectance)
};

// The density with which `strategy` picks w_i at a non-delta vertex.
inline double direction_pdf(Strategy s, const Material& m, const Vec3& n, const Vec3& wo, const Vec3& wi) {
  const double cos_i = dot(n, wi);
  if (cos_i <= 0) return 0.0;
  switch (s) {
    case Strategy::uniform_hemisphere: return uniform_hemisphere_pdf();
    case Strategy::cosine_hemisphere: return cos_i * kInvPi;
    case Strategy::light_area:
    case Strategy::mis:
      if (m.type == MaterialType::phong) {
        const double c = dot(reflect(wo, n), wi);
        return c > 0 ? (m.exponent + 1.0) * kInv2Pi * std::pow(c, m.exponent) : 0.0;
      }
      return cos_i * kInvPi;
  }
  return 0.0;
}

// Samples the next direction the way `strategy` does: uniform or cosine hemisphere for
// the lecture's estimators, the BSDF's own distribution (cosine / Phong lobe) for
// light_area's indirect bounces and MIS; the mirror direction for a mirror.
inline DirectionSample sample_direction(Strategy s, const Material& m, const Vec3& n, const Vec3& wo, Vec2 u) {
  DirectionSample out;
  if (m.is_delta()) {
    out.wi = reflect(wo, n);
    out.delta = true;
    out.pdf = 1.0;
    out.weight = dot(n, out.wi) > 0 ? m.reflectance : Rgb{};
    return out;
  }
  const Frame frame = Frame::from_normal(n);
  if (s == Strategy::uniform_hemisphere) {
    out.wi = frame.to_world(sample_uniform_hemisphere(u));
  } else if (s == Strategy::cosine_hemisphere || m.type != MaterialType::phong) {
    out.wi = frame.to_world(sample_cosine_hemisphere(u));
  } else {
    // Phong lobe around the mirror direction: cos(alpha) = u^(1 / (e + 1)).
    const double cos_a = std::pow(u.x, 1.0 / (m.exponent + 1.0));
    const double sin_a = safe_sqrt(1.0 - cos_a * cos_a);
    const double phi = 2.0 * kPi * u.y;
    const Frame lobe = Frame::from_normal(reflect(wo, n));
    out.wi = lobe.to_world({sin_a * std::cos(phi), sin_a * std::sin(phi), cos_a});
  }
  out.pdf = direction_pdf(s, m, n, wo, out.wi);
  if (out.pdf <= 0 || !std::isfinite(out.pdf)) {
    out.pdf = 0;  // grazing or below the horizon: weight 0, never Inf
    return out;
  }
  out.weight = bsdf_eval(m, n, wo, out.wi) * (dot(n, out.wi) / out.pdf);
  return out;
}

}  // namespace tally
