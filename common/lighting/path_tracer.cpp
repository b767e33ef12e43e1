#include "common/lighting/path_tracer.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <optional>

#include "common/lighting/environment_map.hpp"
#include "common/lighting/pixel_sampler.hpp"
#include "common/lighting/ray_offset.hpp"
#include "common/lighting/texture.hpp"

namespace tally {

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();
// Shadow rays stop this fraction short of the (already offset) light point.
constexpr double kShadowShorten = 1.0 - 1e-5;

double power_heuristic(double a, double b) {
  if (!std::isfinite(a)) return 1.0;
  if (!std::isfinite(b)) return 0.0;
  const double a2 = a * a, b2 = b * b;
  return a2 + b2 > 0 ? a2 / (a2 + b2) : 0.0;
}

}  // namespace

Vertex PathTracer::vertex_at(const Hit& hit, const Vec3& d) const {
  Vertex v{hit.p, hit.n, -d, scene_.shapes[hit.shape].material};
  if (dot(v.n, d) > 0) v.n = -v.n;  // face the incoming ray
  if (hit.has_ns) {
    v.has_ns = true;
    v.ns = dot(hit.ns, v.n) < 0 ? -hit.ns : hit.ns;  // on wo's side, whatever the winding
  }
  v.uv = hit.uv;
  return v;
}

template <class Rng>
Rgb PathTracer::reflected(Vertex v, const PathSettings& s, const Rng& rng, uint32_t dim0, Counters& c) const {
  Rgb L{};
  Rgb beta{1, 1, 1};
  const bool nee = s.strategy == Strategy::light_area || s.strategy == Strategy::mis;
  Material scratch;  // the vertex's material with its textures applied (texture.hpp)
  for (int bounce = 0;; ++bounce) {
    const Material& m = textured_material(scene_, v.material, v.uv, scratch);
    if (!m.reflects() && !plan_.full) break;
    const uint32_t d0 = dim0 + kDimsPerVertex * static_cast<uint32_t>(bounce);
    const Vec3 origin = offset_ray_origin(v.p, v.n);
    // The shading normal (= v.n without vertex normals, and then every line below
    // computes exactly what it did before shading normals existed).
    const Vec3 ns = v.has_ns ? v.ns : v.n;
    auto below_geometric = [&](const Vec3& w) { return v.has_ns && dot(v.n, w) <= 0; };

    if (!m.is_delta()) {
      // The term beta f E cos of one delta light (nullopt: it sends nothing here).
      auto delta_term = [&](const DeltaLight& dl) -> std::optional<Rgb> {
        Vec3 wi;
        double dist = kInf;
        Rgb e = dl.intensity;
        if (dl.type == DeltaLightType::point || dl.type == DeltaLightType::spot) {
          const Vec3 to = dl.position - v.p;
          const double d2 = dot(to, to);
          if (!(d2 > 0)) return std::nullopt;
          dist = std::sqrt(d2);
          wi = to / dist;
          e = e / d2;
          if (dl.type == DeltaLightType::spot) {
            const double fall = spot_falloff(dl, -wi);
            if (!(fall > 0)) return std::nullopt;
            e = e * fall;
          }
        } else {
          wi = dl.direction;
        }
        const double cos_i = dot(ns, wi);
        if (cos_i <= 0 || below_geometric(wi)) return std::nullopt;
        const Rgb f = bsdf_eval(m, ns, v.wo, wi);
        if (is_black(f)) return std::nullopt;
        if (plan_.shadows) {
          c.add(LightingCounter::shadow_rays);
          const Vec3 to = dist < kInf ? dl.position - origin : wi;
          const double len = dist < kInf ? length(to) : 1.0;
          if (accel_.occluded(origin, to / len, dist < kInf ? len * kShadowShorten : kInf)) return std::nullopt;
        }
        return beta * f * e * cos_i;
      };
      if (delta_tree_ == nullptr) {
        for (const DeltaLight& dl : scene_.delta_lights) {
          if (const std::optional<Rgb> t = delta_term(dl)) L += *t;
        }
      } else {
        for (uint32_t i : delta_tree_->directional()) {
          if (const std::optional<Rgb> t = delta_term(scene_.delta_lights[i])) L += *t;
        }
        const uint32_t dim = dim0 + kDimDeltaLightChoice + static_cast<uint32_t>(bounce);
        if (const auto pick = delta_tree_->sample(v.p, rng.uniform(dim))) {
          if (const std::optional<Rgb> t = delta_term(scene_.delta_lights[pick->light])) L += *t / pick->pmf;
        }
      }
      if (nee && !lights_.empty()) {
        c.add(LightingCounter::light_samples);
        const LightSample ls = lights_.sample(v.p, ns, rng.uniform(d0 + kDimLightChoice), rng.uniform(d0 + kDimLightPoint),
                                                rng.uniform(d0 + kDimLightPoint + 1));
        const double cos_i = dot(ns, ls.wi);
        if (ls.pdf > 0 && !is_black(ls.le) && cos_i > 0 && !below_geometric(ls.wi)) {
          const Rgb f = bsdf_eval(m, ns, v.wo, ls.wi);
          if (!is_black(f)) {
            bool visible = true;
            if (plan_.shadows) {
              c.add(LightingCounter::shadow_rays);
              if (ls.sky) {
                visible = !accel_.occluded(origin, ls.wi, kInf);
              } else {
                const Vec3 ln = dot(ls.n, ls.wi) < 0 ? ls.n : -ls.n;  // the side facing v
                const Vec3 target = offset_ray_origin(ls.p, ln);
                const Vec3 to = target - origin;
                const double len = length(to);
                visible = len > 0 && !accel_.occluded(origin, to / len, len * kShadowShorten);
              }
            }
            if (visible) {
              double w = 1.0;
              if (s.strategy == Strategy::mis) {
                w = power_heuristic(ls.pdf, direction_pdf(s.strategy, m, ns, v.wo, ls.wi));
              }
              L += beta * f * ls.le * (cos_i * w / ls.pdf);
            }
          }
        }
      }
    }

    // A BSDF/hemisphere ray is needed if its hit can contribute emission here, or if
    // the path continues from it.
    const bool more_vertices = bounce + 1 < s.max_depth && plan_.indirect;
    const bool gathers = s.strategy != Strategy::light_area || m.is_delta();
    if (!gathers && !more_vertices) break;
    const DirectionSample ds = sample_direction(s.strategy, m, ns, v.wo, {rng.uniform(d0 + kDimDirection), rng.uniform(d0 + kDimDirection + 1)});
    c.add(ds.delta ? LightingCounter::specular_events : LightingCounter::bsdf_samples);
    if (!(ds.pdf > 0) || (is_black(ds.weight) && !plan_.full) || below_geometric(ds.wi)) break;
    const Rgb beta_next = beta * ds.weight;
    // Weight of emission found by this ray (MIS needs the light pdf of its direction).
    auto emission_weight = [&](double light_pdf) {
      if (ds.delta) return 1.0;
      switch (s.strategy) {
        case Strategy::uniform_hemisphere:
        case Strategy::cosine_hemisphere: return 1.0;
        case Strategy::light_area: return 0.0;
        case Strategy::mis: return power_heuristic(ds.pdf, light_pdf);
      }
      return 1.0;
    };
    const bool counts_emission = gathers;
    c.add(LightingCounter::bounce_rays);
    const Vec3 o = dot(ds.wi, v.n) >= 0 ? origin : offset_ray_origin(v.p, -v.n);
    const std::optional<Hit> hit = accel_.intersect(o, ds.wi, kInf);
    if (!hit) {
      if (plan_.sky && (counts_emission || plan_.full)) {
        c.add(LightingCounter::sky_lookups);
        if (has_sky(scene_) && counts_emission) {
          const double w = emission_weight(s.strategy == Strategy::mis && !ds.delta ? lights_.pdf_sky(ns, ds.wi) : 0.0);
          L += beta_next * sky_radiance(scene_, ds.wi) * w;
        }
      }
      break;
    }
    if (plan_.emission && (counts_emission || plan_.full)) {
      c.add(LightingCounter::emission_lookups);
      const Rgb le = emitted(scene_, hit->shape, hit->n, -ds.wi, hit->uv);
      if (!is_black(le) && counts_emission) {
        // The light pdf of the direction ds.wi at v.p, where light samples are drawn from,
        // not pdf_hit(v.p, hit): the hit was found by a ray from the offset origin o, and
        // seen from v.p it lies in another direction. On an emitter (the furnace sphere)
        // grazing rays hit at |hit - v.p| ~ |o - v.p|, so that pdf was too high by
        // (eps/2R) tan^2(theta), the BSDF weights too low, and MIS -1.5e-5 low.
        const double w = emission_weight(s.strategy == Strategy::mis && !ds.delta ? lights_.pdf_dir(v.p, ds.wi, *hit) : 0.0);
        L += beta_next * le * w;
      }
    }
    if (!more_vertices) break;
    beta = beta_next;
    if (s.russian_roulette && bounce + 1 >= 2) {
      const double q = std::clamp(max_component(beta), 0.05, 1.0);
      if (rng.uniform(d0 + kDimRoulette) >= q) {
        c.add(LightingCounter::roulette_terminations);
        break;
      }
      beta = beta / q;
    }
    v = vertex_at(*hit, ds.wi);
  }
  return L;
}

template <class Rng>
Rgb PathTracer::camera(const Vec3& o, const Vec3& d, const PathSettings& s, const Rng& rng, uint32_t dim0,
                       Counters& c) const {
  c.add(LightingCounter::camera_rays);
  const std::optional<Hit> hit = accel_.intersect(o, d, kInf);
  if (!hit) {
    if (plan_.sky) {
      c.add(LightingCounter::sky_lookups);
      if (has_sky(scene_)) return sky_radiance(scene_, d);
    }
    return {};
  }
  Rgb L{};
  if (plan_.emission) {
    c.add(LightingCounter::emission_lookups);
    L += emitted(scene_, hit->shape, hit->n, -d, hit->uv);
  }
  L += reflected(vertex_at(*hit, d), s, rng, dim0, c);
  return L;
}

template Rgb PathTracer::reflected<SampleRng>(Vertex, const PathSettings&, const SampleRng&, uint32_t, Counters&) const;
template Rgb PathTracer::reflected<SobolSample>(Vertex, const PathSettings&, const SobolSample&, uint32_t, Counters&) const;
template Rgb PathTracer::camera<SampleRng>(const Vec3&, const Vec3&, const PathSettings&, const SampleRng&, uint32_t,
                                           Counters&) const;
template Rgb PathTracer::camera<SobolSample>(const Vec3&, const Vec3&, const PathSettings&, const SobolSample&, uint32_t,
                                             Counters&) const;

}  // namespace tally
