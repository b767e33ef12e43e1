#pragma once
// The reflection models: Lambertian (diffuse, and the reflective part of emissive
// materials), a perfect mirror (a delta distribution), normalised Phong,
//   f = k_d / pi + k_s (e + 2) / (2 pi) cos^e(alpha),  alpha = angle(w_i, mirror(w_o)),
// (k_d = 0 unless an OBJ .mtl gives both Kd and Ks) whose albedo is <= k_d + k_s, and
// glTF's metallic-roughness model in one of two forms (Material::model; docs/lighting.md,
// "Glossy materials"). With S = D(h) G2(w_o, w_i) / (4 cos_o cos_i) the GGX specular lobe,
// F_d(c) = Schlick with F0 = min(0.04 specular_color, 1) specular and F90 = specular
// (KHR_materials_specular; 0.04 and 1 without it), F_m(c) Schlick with F0 = base:
//   gltf_reference (glTF 2.0 Appendix B: mix(fresnel_mix(ior 1.5, diffuse, specular),
//   conductor_fresnel(base, specular), metallic)), per colour channel:
//     f = (1 - metallic) [(1 - F_d(w_o.h)) base / pi + F_d(w_o.h) S] + metallic F_m(w_o.h) S
//   energy_conserving:
//     f = F(w_o.h) S + (1 - metallic) base / pi (1 - F_d(cos_o)) (1 - F_d(cos_i))
//     with F = Schlick at F0 = lerp(F0_d, base, metallic), F90 = lerp(F90_d, 1, metallic)
//     and F_d taken on its largest channel: the diffuse layer gets what the dielectric
//     coating transmits on the way in and out, so the albedo stays <= 1 (a furnace test
//     checks it). The reference form reflects more than 1 at grazing angles (its diffuse
//     term is weighted by F at the half vector, not at the directions themselves).
// Both are reciprocal. Trowbridge-Reitz D and Smith's height-correlated G2 at alpha =
// roughness^2. Specular directions are drawn from the distribution of visible normals
// (Heitz 2018, "Sampling the GGX Distribution of Visible Normals", JCGT 7(4)); the lobe is
// chosen by the form's own weights at w_o, and the pdf is the mixture. Directions are in
// world space; `n` is the unit (shading) normal on the side of w_o. Every routine
// returns 0 (never NaN/Inf) below the horizon.
#include <algorithm>
#include <cmath>

#include "common/lighting/scene.hpp"
#include "common/sampling/safe_math.hpp"
#include "common/sampling/sphere.hpp"

namespace tally {

enum class Strategy { uniform_hemisphere, cosine_hemisphere, light_area, mis };

inline Vec3 reflect(const Vec3& wo, const Vec3& n) { return n * (2.0 * dot(n, wo)) - wo; }

// GGX below this alpha (roughness 0.0316) is clamped: D's peak 1/(pi alpha^2) stays finite.
inline constexpr double kMinGgxAlpha = 1e-3;
inline constexpr double kDielectricF0 = 0.04;  // glTF's dielectric (IOR 1.5)

inline double ggx_alpha(double roughness) { return std::max(roughness * roughness, kMinGgxAlpha); }

// Trowbridge-Reitz normal distribution at cos(theta_h) = c.
inline double ggx_d(double c, double alpha) {
  if (c <= 0) return 0.0;
  const double a2 = alpha * alpha;
  const double d = c * c * (a2 - 1.0) + 1.0;
  return a2 / (kPi * d * d);
}

// Smith's Lambda for GGX at cos(theta) = c > 0.
inline double ggx_lambda(double c, double alpha) {
  const double c2 = c * c;
  const double t2 = std::max(0.0, 1.0 - c2) / c2;
  return 0.5 * (std::sqrt(1.0 + alpha * alpha * t2) - 1.0);
}
inline double ggx_g1(double c, double alpha) { return c > 0 ? 1.0 / (1.0 + ggx_lambda(c, alpha)) : 0.0; }

inline double schlick_weight(double c) {
  const double m = std::clamp(1.0 - c, 0.0, 1.0);
  const double m2 = m * m;
  return m2 * m2 * m;
}
inline Rgb schlick(const Rgb& f0, double c) {
  const double w = schlick_weight(c);
  return f0 + (Rgb{1, 1, 1} - f0) * w;
}
inline double schlick(double f0, double c) { return f0 + (1.0 - f0) * schlick_weight(c); }
// Schlick with a reflectance f90 at grazing incidence (KHR_materials_specular); at
// f90 = 1 it is bit for bit the two-argument form.
inline Rgb schlick(const Rgb& f0, double f90, double c) {
  const double w = schlick_weight(c);
  return f0 + (Rgb{f90, f90, f90} - f0) * w;
}
inline double schlick(double f0, double f90, double c) { return f0 + (f90 - f0) * schlick_weight(c); }

// The dielectric layer's normal-incidence reflectance: min(0.04 specular_color, 1) x
// specular (exactly 0.04 without KHR_materials_specular).
inline Rgb dielectric_f0(const Material& m) {
  const Rgb c = m.specular_color * kDielectricF0;
  return Rgb{std::min(c.x, 1.0), std::min(c.y, 1.0), std::min(c.z, 1.0)} * m.specular;
}
// The specular layer's F0 and F90 mixed by metallic (base colour as F0 of metals).
inline Rgb mr_f0(const Material& m) { return dielectric_f0(m) * (1.0 - m.metallic) + m.base_color * m.metallic; }
inline double mr_f90(const Material& m) { return m.specular + (1.0 - m.specular) * m.metallic; }

// The energy-conserving form's scalar Fresnel of the coating over the diffuse base:
// Schlick on the largest channel of the dielectric F0 (0.04 without the extension).
inline double coating_fresnel(const Material& m, double c) {
  const Rgb f0 = dielectric_f0(m);
  return schlick(std::max({f0.x, f0.y, f0.z}), m.specular, c);
}

// The weight of the diffuse base at cos_o for lobe selection (its albedo, roughly).
inline double mr_diffuse_weight(const Material& m, double cos_o) {
  if (m.model == MaterialModel::gltf_reference) {
    return luminance(m.base_color * (Rgb{1, 1, 1} - schlick(dielectric_f0(m), m.specular, cos_o))) * (1.0 - m.metallic);
  }
  return luminance(m.base_color) * (1.0 - m.metallic) * (1.0 - coating_fresnel(m, cos_o));
}

// Probability that metallic-roughness sampling picks the specular lobe: the lobes'
// albedos at w_o, estimated by Schlick's F at cos_o (1 for a pure metal).
inline double mr_specular_probability(const Material& m, double cos_o) {
  const double ws = luminance(schlick(mr_f0(m), mr_f90(m), cos_o));
  const double wd = mr_diffuse_weight(m, cos_o);
  return ws + wd > 0 ? ws / (ws + wd) : 1.0;
}

// Probability that Phong with a diffuse part (OBJ Kd + Ks) samples the Phong lobe.
inline double phong_lobe_probability(const Material& m) {
  const double ws = luminance(m.reflectance), wd = luminance(m.albedo);
  return ws + wd > 0 ? ws / (ws + wd) : 1.0;
}

inline Rgb mr_eval(const Material& m, const Vec3& n, const Vec3& wo, const Vec3& wi) {
  const double cos_o = dot(n, wo), cos_i = dot(n, wi);
  if (cos_o <= 0 || cos_i <= 0) return {};
  const Vec3 hv = wo + wi;
  const double hl = length(hv);
  if (m.model == MaterialModel::gltf_reference) {
    if (!(hl > 0)) return {};
    const Vec3 h = hv / hl;
    const double voh = dot(wo, h);
    const double alpha = ggx_alpha(m.roughness);
    const double g2 = 1.0 / (1.0 + ggx_lambda(cos_o, alpha) + ggx_lambda(cos_i, alpha));
    const double s = ggx_d(dot(n, h), alpha) * g2 / (4.0 * cos_o * cos_i);
    const Rgb fd = schlick(dielectric_f0(m), m.specular, voh);
    const Rgb fm = schlick(m.base_color, voh);
    const Rgb diffuse = (Rgb{1, 1, 1} - fd) * m.base_color * ((1.0 - m.metallic) * kInvPi);
    return diffuse + (fd * (1.0 - m.metallic) + fm * m.metallic) * s;
  }
  Rgb f{};
  if (hl > 0) {
    const Vec3 h = hv / hl;
    const double alpha = ggx_alpha(m.roughness);
    const double g2 = 1.0 / (1.0 + ggx_lambda(cos_o, alpha) + ggx_lambda(cos_i, alpha));
    f = schlick(mr_f0(m), mr_f90(m), dot(wo, h)) * (ggx_d(dot(n, h), alpha) * g2 / (4.0 * cos_o * cos_i));
  }
  const double kd = (1.0 - m.metallic) * (1.0 - coating_fresnel(m, cos_o)) * (1.0 - coating_fresnel(m, cos_i));
  return f + m.base_color * (kd * kInvPi);
}

// Solid-angle density of a visible-normal GGX sample w_i (reflected about h).
inline double ggx_vndf_pdf(const Vec3& n, const Vec3& wo, const Vec3& wi, double alpha) {
  const double cos_o = dot(n, wo);
  if (cos_o <= 0 || dot(n, wi) <= 0) return 0.0;
  const Vec3 hv = wo + wi;
  const double hl = length(hv);
  if (!(hl > 0)) return 0.0;
  const Vec3 h = hv / hl;
  if (dot(wo, h) <= 0) return 0.0;
  return ggx_g1(cos_o, alpha) * ggx_d(dot(n, h), alpha) / (4.0 * cos_o);
}

inline double mr_pdf(const Material& m, const Vec3& n, const Vec3& wo, const Vec3& wi) {
  const double cos_i = dot(n, wi);
  if (cos_i <= 0) return 0.0;
  const double ps = mr_specular_probability(m, dot(n, wo));
  return ps * ggx_vndf_pdf(n, wo, wi, ggx_alpha(m.roughness)) + (1.0 - ps) * cos_i * kInvPi;
}

// Heitz 2018, listing 1 (isotropic alpha): a visible normal for w_o (local frame, z = n).
inline Vec3 sample_ggx_vndf(const Vec3& wo_local, double alpha, Vec2 u) {
  const Vec3 vh = normalize(Vec3{alpha * wo_local.x, alpha * wo_local.y, wo_local.z});
  const double lensq = vh.x * vh.x + vh.y * vh.y;
  const Vec3 t1 = lensq > 0 ? Vec3{-vh.y, vh.x, 0.0} / std::sqrt(lensq) : Vec3{1, 0, 0};
  const Vec3 t2 = cross(vh, t1);
  const double r = std::sqrt(u.x);
  const double phi = 2.0 * kPi * u.y;
  const double p1 = r * std::cos(phi);
  double p2 = r * std::sin(phi);
  const double s = 0.5 * (1.0 + vh.z);
  p2 = (1.0 - s) * safe_sqrt(1.0 - p1 * p1) + s * p2;
  const Vec3 nh = t1 * p1 + t2 * p2 + vh * safe_sqrt(1.0 - p1 * p1 - p2 * p2);
  return normalize(Vec3{alpha * nh.x, alpha * nh.y, std::max(0.0, nh.z)});
}

// Picks a lobe with u.x < p and rescales u.x to [0, 1) for the lobe's own sampler.
inline double rescale_choice(double x, double p, bool first) {
  const double r = first ? x / p : (x - p) / (1.0 - p);
  return std::clamp(r, 0.0, std::nextafter(1.0, 0.0));
}

// f_r(w_i -> w_o) for non-delta materials (mirror: 0).
inline Rgb bsdf_eval(const Material& m, const Vec3& n, const Vec3& wo, const Vec3& wi) {
  if (dot(n, wi) <= 0) return {};
  switch (m.type) {
    case MaterialType::diffuse:
    case MaterialType::emissive: return m.albedo * kInvPi;
    case MaterialType::phong: {
      const double c = dot(reflect(wo, n), wi);
      const Rgb spec = c <= 0 ? Rgb{} : m.reflectance * ((m.exponent + 2.0) * kInv2Pi * std::pow(c, m.exponent));
      return is_black(m.albedo) ? spec : spec + m.albedo * kInvPi;
    }
    case MaterialType::metallic_roughness: return mr_eval(m, n, wo, wi);
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
        const double lobe = c > 0 ? (m.exponent + 1.0) * kInv2Pi * std::pow(c, m.exponent) : 0.0;
        if (is_black(m.albedo)) return lobe;
        const double ps = phong_lobe_probability(m);
        return ps * lobe + (1.0 - ps) * cos_i * kInvPi;
      }
      if (m.type == MaterialType::metallic_roughness) return mr_pdf(m, n, wo, wi);
      return cos_i * kInvPi;
  }
  return 0.0;
}

// Samples the next direction the way `strategy` does: uniform or cosine hemisphere for
// the lecture's estimators, the BSDF's own distribution (cosine / Phong lobe) for
// light_area's indirect bounces and MIS; the mirror direction for a mirror. Two-lobe
// materials (metallic-roughness, Phong with a diffuse part) pick a lobe with u.x and
// reuse its rescaled remainder; the pdf is the mixture's (one-sample MIS of the lobes).
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
  } else if (s == Strategy::cosine_hemisphere ||
             (m.type != MaterialType::phong && m.type != MaterialType::metallic_roughness)) {
    out.wi = frame.to_world(sample_cosine_hemisphere(u));
  } else if (m.type == MaterialType::metallic_roughness) {
    const double ps = mr_specular_probability(m, dot(n, wo));
    if (u.x < ps) {
      const Vec3 h = frame.to_world(
          sample_ggx_vndf(frame.to_local(wo), ggx_alpha(m.roughness), {rescale_choice(u.x, ps, true), u.y}));
      out.wi = reflect(wo, h);
    } else {
      out.wi = frame.to_world(sample_cosine_hemisphere({rescale_choice(u.x, ps, false), u.y}));
    }
  } else if (!is_black(m.albedo) && u.x >= phong_lobe_probability(m)) {
    out.wi = frame.to_world(sample_cosine_hemisphere({rescale_choice(u.x, phong_lobe_probability(m), false), u.y}));
  } else {
    if (!is_black(m.albedo)) u.x = rescale_choice(u.x, phong_lobe_probability(m), true);
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
