// The GGX / metallic-roughness BSDF (common/lighting/bsdf.hpp): a white furnace (the
// albedo never exceeds 1, and a smooth white metal keeps nearly all of it), the
// sampler against the pdf MIS uses (chi-square, Šidák over the cases), and the sampled
// estimate of the albedo against an independent uniform-hemisphere estimate of ∫ f cos.
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "common/lighting/bsdf.hpp"
#include "common/rng/counter_rng.hpp"
#include "support/chi_square.hpp"

namespace tally {
namespace {

Material metal(double f0, double roughness) {
  Material m;
  m.type = MaterialType::metallic_roughness;
  m.base_color = {f0, f0, f0};
  m.metallic = 1.0;
  m.roughness = roughness;
  return m;
}

Material plastic(double base, double metallic, double roughness) {
  Material m = metal(base, roughness);
  m.metallic = metallic;
  return m;
}

// The same material in glTF's reference form (bsdf.hpp), with KHR_materials_specular's
// factors.
Material reference(Material m, double specular = 1.0, Rgb specular_color = {1, 1, 1}) {
  m.model = MaterialModel::gltf_reference;
  m.specular = specular;
  m.specular_color = specular_color;
  return m;
}

Vec3 wo_at(double cos_o) { return {std::sqrt(std::max(0.0, 1.0 - cos_o * cos_o)), 0.0, cos_o}; }

struct Estimate {
  double mean = 0, se = 0;
};

// Albedo at w_o by the BSDF's own sampling: mean of f cos / pdf (no-samples count 0).
Estimate sampled_albedo(const Material& m, const Vec3& wo, uint64_t n, uint64_t seed) {
  const Vec3 nrm{0, 0, 1};
  double s = 0, s2 = 0;
  for (uint64_t i = 0; i < n; ++i) {
    const SampleRng rng(seed, i);
    const DirectionSample ds = sample_direction(Strategy::mis, m, nrm, wo, {rng.uniform(0), rng.uniform(1)});
    const double w = ds.pdf > 0 ? ds.weight.y : 0.0;
    EXPECT_TRUE(std::isfinite(w));
    s += w;
    s2 += w * w;
  }
  const double mean = s / static_cast<double>(n);
  const double var = std::max(0.0, s2 / static_cast<double>(n) - mean * mean);
  return {mean, std::sqrt(var / static_cast<double>(n))};
}

// The same integral by uniform hemisphere sampling (independent of the BSDF's sampler).
Estimate uniform_albedo(const Material& m, const Vec3& wo, uint64_t n, uint64_t seed) {
  const Vec3 nrm{0, 0, 1};
  double s = 0, s2 = 0;
  for (uint64_t i = 0; i < n; ++i) {
    const SampleRng rng(seed, i);
    const Vec3 wi = sample_uniform_hemisphere({rng.uniform(0), rng.uniform(1)});
    const double w = bsdf_eval(m, nrm, wo, wi).y * wi.z * 2.0 * kPi;
    s += w;
    s2 += w * w;
  }
  const double mean = s / static_cast<double>(n);
  const double var = std::max(0.0, s2 / static_cast<double>(n) - mean * mean);
  return {mean, std::sqrt(var / static_cast<double>(n))};
}

TEST(Ggx, WhiteFurnaceAlbedoAtMostOne) {
  // Every roughness / angle / model: albedo <= 1 + 4 se (90 cases, 4 sd each: the
  // false-failure rate is < 1e-3). A smooth white metal keeps nearly all the energy:
  // >= 0.97 at roughness <= 0.1 and cos_o >= 0.2, >= 0.95 at roughness 0.3 and
  // cos_o >= 0.4 (single-scattering GGX loses what the masking term G2/G1 removes: 8.5%
  // at roughness 0.3, cos_o 0.2, measured; at roughness 1 (alpha 1) and normal incidence
  // the albedo is 1 - ln 2 = 0.307 in closed form, measured 0.3068 +- 0.0018 -- the known
  // deficit of single-scattering microfacet models).
  uint64_t seed = 1;
  for (double r : {0.0, 0.1, 0.3, 0.5, 0.8, 1.0}) {
    for (double c : {1.0, 0.7, 0.4, 0.2, 0.05}) {
      for (const Material& m : {metal(1.0, r), plastic(1.0, 0.0, r), plastic(1.0, 0.5, r)}) {
        const Estimate e = sampled_albedo(m, wo_at(c), 40000, ++seed);
        EXPECT_LE(e.mean, 1.0 + 4.0 * e.se) << "roughness " << r << " cos_o " << c << " metallic " << m.metallic;
        if (m.metallic == 1.0 && r <= 0.1 && c >= 0.2) {
          EXPECT_GE(e.mean, 0.97) << "roughness " << r << " cos_o " << c;
        }
        if (m.metallic == 1.0 && r == 0.3 && c >= 0.4) {
          EXPECT_GE(e.mean, 0.95) << "cos_o " << c;
        }
      }
    }
  }
}

TEST(Ggx, AlbedoOfTheRoughestWhiteMetalIsOneMinusLn2) {
  // alpha = 1, normal incidence, F0 = 1: D = 1/pi, G2 = 2 cos_i / (1 + cos_i), so the
  // albedo is (1/4pi) ∫ G2 dw = 1 - ln 2.
  const Estimate e = sampled_albedo(metal(1.0, 1.0), wo_at(1.0), 400000, 4242);
  EXPECT_NEAR(e.mean, 1.0 - std::log(2.0), 4.0 * e.se);
  EXPECT_LT(e.se, 2e-3);
}

TEST(Ggx, SampledAlbedoMatchesUniformEstimate) {
  // E[f cos / pdf] under the BSDF's sampler equals ∫ f cos dw estimated with uniform
  // directions: the pdf the sampler reports is the density it samples with (4 se of the
  // difference, 18 cases, false-failure rate ~ 1.2e-3; half in glTF's reference form,
  // one with KHR_materials_specular's factor and a coloured specular).
  uint64_t seed = 1000;
  for (double r : {0.3, 0.6, 1.0}) {
    for (const Material& m : {metal(0.9, r), plastic(0.8, 0.0, r), plastic(0.6, 0.3, r), reference(plastic(0.8, 0.0, r)),
                              reference(plastic(0.6, 0.3, r), 0.5, {1.0, 0.5, 2.0}), reference(metal(0.9, r))}) {
      const Vec3 wo = wo_at(0.6);
      const Estimate a = sampled_albedo(m, wo, 200000, ++seed);
      const Estimate b = uniform_albedo(m, wo, 200000, ++seed);
      EXPECT_NEAR(a.mean, b.mean, 4.0 * std::hypot(a.se, b.se)) << "roughness " << r << " metallic " << m.metallic;
    }
  }
}

using test::chi_square_p;

TEST(Ggx, ChiSquareSamplingAgainstPdf) {
  // Directions binned in (cos theta, phi) cells of the hemisphere (+ one cell for "no
  // sample": a specular direction below the horizon); expected = N ∫ direction_pdf over
  // the cell (midpoint rule on 8x8 sub-cells). Šidák: each case at 1 - 0.99^(1/7), so
  // the false-failure rate of the whole test is 1%. The last three cases are glTF's
  // reference form (one with specularFactor 0.3 and a coloured specular). Lobes much
  // sharper than roughness 0.5 at grazing w_o (e.g. 0.3 at cos_o 0.2) fail in either
  // form: the midpoint rule on this grid no longer integrates the pdf over a cell.
  struct Case {
    Material m;
    double cos_o;
  };
  const std::vector<Case> cases = {{metal(1.0, 0.5), 0.8}, {metal(0.7, 0.8), 0.3},
                                   {plastic(0.8, 0.0, 0.6), 0.5}, {plastic(0.5, 0.5, 1.0), 0.95},
                                   {reference(plastic(0.8, 0.0, 0.6)), 0.5}, {reference(plastic(0.5, 0.5, 0.7)), 0.2},
                                   {reference(plastic(0.7, 0.0, 0.4), 0.3, {1.0, 0.6, 0.2}), 0.7}};
  const double alpha_each = 1.0 - std::pow(0.99, 1.0 / static_cast<double>(cases.size()));
  const int GC = 32, GP = 16, S = 8;
  const uint64_t N = 500000;
  const Vec3 n{0, 0, 1};
  uint64_t seed = 77;
  for (const Case& c : cases) {
    const Vec3 wo = wo_at(c.cos_o);
    std::vector<double> obs(GC * GP + 1, 0), expct(GC * GP + 1, 0);
    for (uint64_t i = 0; i < N; ++i) {
      const SampleRng rng(seed, i);
      const DirectionSample ds = sample_direction(Strategy::mis, c.m, n, wo, {rng.uniform(0), rng.uniform(1)});
      if (!(ds.pdf > 0)) {
        obs[GC * GP] += 1;
        continue;
      }
      EXPECT_NEAR(ds.pdf, direction_pdf(Strategy::mis, c.m, n, wo, ds.wi), 1e-9 * ds.pdf);
      const double phi = std::atan2(ds.wi.y, ds.wi.x) + kPi;
      const int ic = std::clamp(static_cast<int>(ds.wi.z * GC), 0, GC - 1);
      const int ip = std::clamp(static_cast<int>(phi / (2 * kPi) * GP), 0, GP - 1);
      obs[static_cast<size_t>(ic * GP + ip)] += 1;
    }
    double total = 0;
    for (int ic = 0; ic < GC; ++ic) {
      for (int ip = 0; ip < GP; ++ip) {
        double prob = 0;
        for (int k = 0; k < S * S; ++k) {
          const double z = (ic + (k % S + 0.5) / S) / GC;
          const double phi = (ip + (k / S + 0.5) / S) / GP * 2 * kPi - kPi;
          const double sr = std::sqrt(1 - z * z);
          const Vec3 wi{sr * std::cos(phi), sr * std::sin(phi), z};
          prob += direction_pdf(Strategy::mis, c.m, n, wo, wi) * (2 * kPi) / (GC * GP * S * S);
        }
        expct[static_cast<size_t>(ic * GP + ip)] = prob * static_cast<double>(N);
        total += prob;
      }
    }
    EXPECT_LE(total, 1.0 + 1e-3);
    expct[GC * GP] = std::max(0.0, 1.0 - total) * static_cast<double>(N);
    EXPECT_GT(chi_square_p(obs, expct), alpha_each) << "roughness " << c.m.roughness << " metallic " << c.m.metallic;
    ++seed;
  }
}

TEST(Ggx, ReferenceFormAlbedo) {
  // glTF's reference form: a metal is the energy-conserving form's metal bit for bit
  // (F(w_o.h) S in both), so its albedo is <= 1; the dielectric's albedo is <= 1 near
  // normal incidence but exceeds 1 at grazing angles (its diffuse term is weighted by
  // 1 - F(w_o.h), close to 0.96 for most w_i, while the specular lobe reflects nearly
  // all at grazing): white base, roughness 0.3, cos_o 0.05 measured > 1.3. 4 se each
  // (18 comparisons, false-failure rate < 1e-3).
  uint64_t seed = 500;
  for (double r : {0.1, 0.5, 1.0}) {
    for (double c : {1.0, 0.5, 0.05}) {
      const Estimate e = sampled_albedo(reference(metal(1.0, r)), wo_at(c), 40000, ++seed);
      EXPECT_LE(e.mean, 1.0 + 4.0 * e.se) << "roughness " << r << " cos_o " << c;
      const Vec3 n{0, 0, 1};
      for (uint64_t i = 0; i < 64; ++i) {
        const SampleRng rng(seed, i);
        const Vec3 wi = sample_uniform_hemisphere({rng.uniform(0), rng.uniform(1)});
        const Rgb a = bsdf_eval(reference(metal(0.8, r)), n, wo_at(c), wi), b = bsdf_eval(metal(0.8, r), n, wo_at(c), wi);
        EXPECT_TRUE(a.x == b.x && a.y == b.y && a.z == b.z) << "roughness " << r << " cos_o " << c;
      }
    }
    const Estimate normal = sampled_albedo(reference(plastic(1.0, 0.0, r)), wo_at(1.0), 40000, ++seed);
    EXPECT_LE(normal.mean, 1.0 + 4.0 * normal.se) << "roughness " << r;
  }
  const Estimate grazing = sampled_albedo(reference(plastic(1.0, 0.0, 0.3)), wo_at(0.05), 40000, 999);
  EXPECT_GT(grazing.mean, 1.3);
}

TEST(Ggx, SpecularFactorZeroIsExactlyLambert) {
  // KHR_materials_specular with specularFactor 0: F0 = F90 = 0, no specular layer, and
  // the reference form's base is weighted by 1 - F = 1: f = base / pi exactly, sampled
  // cosine-weighted (the lobe choice gives the specular lobe probability 0), so every
  // sample's weight is the base colour and the albedo is exactly the base (white
  // furnace: 0.7 with no variance), for any roughness, metallic 0.
  const Vec3 n{0, 0, 1};
  for (double r : {0.0, 0.4, 1.0}) {
    const Material m = reference(plastic(0.7, 0.0, r), 0.0, {1.0, 0.5, 0.2});
    for (double c : {1.0, 0.3, 0.01}) {
      const Vec3 wo = wo_at(c);
      EXPECT_EQ(mr_specular_probability(m, c), 0.0);
      for (uint64_t i = 0; i < 256; ++i) {
        const SampleRng rng(31, i);
        const DirectionSample ds = sample_direction(Strategy::mis, m, n, wo, {rng.uniform(0), rng.uniform(1)});
        ASSERT_GT(ds.pdf, 0.0);
        EXPECT_NEAR(ds.weight.y, 0.7, 1e-15);
        EXPECT_NEAR(bsdf_eval(m, n, wo, ds.wi).y, 0.7 * kInvPi, 1e-16);
        EXPECT_NEAR(ds.pdf, ds.wi.z * kInvPi, 1e-15);
      }
    }
  }
}

TEST(Ggx, BothFormsAreReciprocal) {
  // f(w_o, w_i) = f(w_i, w_o) (F at w_o.h = w_i.h; the energy-conserving diffuse weight
  // is symmetric), to rounding, over random direction pairs.
  const Vec3 n{0, 0, 1};
  for (const Material& m : {plastic(0.6, 0.3, 0.5), reference(plastic(0.6, 0.3, 0.5)),
                            reference(plastic(0.9, 0.0, 0.2), 0.4, {1.0, 0.3, 0.7}), reference(metal(0.7, 0.8))}) {
    for (uint64_t i = 0; i < 1000; ++i) {
      const SampleRng rng(77, i);
      const Vec3 a = sample_uniform_hemisphere({rng.uniform(0), rng.uniform(1)});
      const Vec3 b = sample_uniform_hemisphere({rng.uniform(2), rng.uniform(3)});
      const Rgb fab = bsdf_eval(m, n, a, b), fba = bsdf_eval(m, n, b, a);
      EXPECT_NEAR(fab.x, fba.x, 1e-12 * (1 + fab.x));
      EXPECT_NEAR(fab.z, fba.z, 1e-12 * (1 + fab.z));
    }
  }
}

TEST(Ggx, NeverNanAtGrazingAndSmoothLimits) {
  const Vec3 n{0, 0, 1};
  for (double r : {0.0, 1e-4, 1.0}) {
    for (double c : {1.0, 1e-8, 0.0}) {
      for (const Material& m : {plastic(0.5, 0.5, r), reference(plastic(0.5, 0.5, r), 0.5)})
      for (uint64_t i = 0; i < 1000; ++i) {
        const SampleRng rng(5, i);
        const DirectionSample ds = sample_direction(Strategy::mis, m, n, wo_at(c), {rng.uniform(0), rng.uniform(1)});
        EXPECT_TRUE(std::isfinite(ds.pdf));
        EXPECT_TRUE(std::isfinite(ds.weight.x) && std::isfinite(ds.weight.y) && std::isfinite(ds.weight.z));
      }
    }
  }
}

}  // namespace
}  // namespace tally
