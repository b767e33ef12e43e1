#include "common/lighting/light_set.hpp"

#include "common/lighting/environment_map.hpp"
#include "common/lighting/scene_bounds.hpp"
#include "common/lighting/texture.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "common/sampling/disk.hpp"
#include "common/sampling/safe_math.hpp"
#include "common/sampling/sphere.hpp"
#include "common/sampling/triangle.hpp"

namespace tally {

namespace {
constexpr double kInf = std::numeric_limits<double>::infinity();

// Outside the sphere by a relative margin: then the cone sampler applies.
bool outside_sphere(const Shape& s, const Vec3& x) {
  const Vec3 d = s.center - x;
  return dot(d, d) > s.radius * s.radius * (1.0 + 1e-6);
}

double cone_cos_max(const Shape& s, const Vec3& x) {
  const Vec3 d = s.center - x;
  const double sin2 = s.radius * s.radius / dot(d, d);
  return safe_sqrt(1.0 - sin2);
}

// The same conversion and the same rejections as LightSample::sample's area branch.
double area_to_solid_angle(double pdf_area, const Vec3& x, const Vec3& p, const Vec3& n) {
  const Vec3 d = p - x;
  const double d2 = dot(d, d);
  if (!(d2 > 0)) return 0.0;
  const double cos_l = std::fabs(dot(n, d)) / std::sqrt(d2);
  if (!(cos_l > kMinLightCos)) return 0.0;
  const double pdf = pdf_area * d2 / cos_l;
  return std::isfinite(pdf) ? pdf : 0.0;
}
}  // namespace

Rgb emitted(const Scene& scene, uint32_t shape, const Vec3& n, const Vec3& w, Vec2 uv) {
  const Material& m = scene.materials[scene.shapes[shape].material];
  if (!m.emits()) return {};
  if (m.two_sided || dot(n, w) > 0) return textured_emission(scene, m, uv);
  return {};
}

double light_power_radiance(const Rgb& radiance) {
  const double peak = std::max({radiance.x, radiance.y, radiance.z});
  return std::max(luminance(radiance), 1e-3 * peak);
}

namespace {
Vec3 vmin(const Vec3& a, const Vec3& b) { return {std::min(a.x, b.x), std::min(a.y, b.y), std::min(a.z, b.z)}; }
Vec3 vmax(const Vec3& a, const Vec3& b) { return {std::max(a.x, b.x), std::max(a.y, b.y), std::max(a.z, b.z)}; }

// The tree's bounds of an emitter entry (phi set by the caller): its box, its normal
// (all directions for spheres) and the 90-degree emission spread of an area light.
LightBounds entry_bounds(const Shape& s, uint32_t triangle, bool two_sided) {
  LightBounds b;
  b.two_sided = two_sided;
  b.cos_e = 0.0;
  switch (s.type) {
    case ShapeType::sphere: {
      const Vec3 r{s.radius, s.radius, s.radius};
      b.lo = s.center - r;
      b.hi = s.center + r;
      b.cos_o = -1.0;
      break;
    }
    case ShapeType::disk: {
      const Vec3 r{s.radius, s.radius, s.radius};
      b.lo = s.center - r;
      b.hi = s.center + r;
      b.w = s.normal;
      break;
    }
    case ShapeType::quad: {
      const Vec3 c[4] = {s.corner, s.corner + s.edge_u, s.corner + s.edge_v, s.corner + s.edge_u + s.edge_v};
      b.lo = b.hi = c[0];
      for (const Vec3& v : c) {
        b.lo = vmin(b.lo, v);
        b.hi = vmax(b.hi, v);
      }
      b.w = normalize(cross(s.edge_u, s.edge_v));
      break;
    }
    case ShapeType::mesh: {
      const auto& tri = s.triangles[triangle];
      const Vec3 &a = s.vertices[tri[0]], &v1 = s.vertices[tri[1]], &v2 = s.vertices[tri[2]];
      b.lo = vmin(a, vmin(v1, v2));
      b.hi = vmax(a, vmax(v1, v2));
      const Vec3 nn = cross(v1 - a, v2 - a);
      const double len = length(nn);
      if (len > 0) {
        b.w = nn / len;
      } else {
        b.cos_o = -1.0;
      }
      break;
    }
  }
  return b;
}
}  // namespace

LightSet::LightSet(const Scene& scene, LightSelection selection)
    : scene_(scene), light_of_shape_(scene.shapes.size(), -1) {
  sky_ = sky_emits(scene);
  std::vector<double> weights;
  for (uint32_t i = 0; i < scene.shapes.size(); ++i) {
    const Shape& s = scene.shapes[i];
    const Material& m = scene.materials[s.material];
    if (!m.emits()) continue;
    AreaLight l;
    l.shape = i;
    std::vector<double> tri_area;
    switch (s.type) {
      case ShapeType::sphere: l.area = 4.0 * kPi * s.radius * s.radius; break;
      case ShapeType::disk: l.area = kPi * s.radius * s.radius; break;
      case ShapeType::quad: l.area = length(cross(s.edge_u, s.edge_v)); break;
      case ShapeType::mesh: {
        tri_area.resize(s.triangles.size());
        for (size_t t = 0; t < tri_area.size(); ++t) {
          const auto& tri = s.triangles[t];
          tri_area[t] = triangle_area(s.vertices[tri[0]], s.vertices[tri[1]], s.vertices[tri[2]]);
          if (!std::isfinite(tri_area[t])) tri_area[t] = 0;
          l.area += tri_area[t];
        }
        break;
      }
    }
    if (!(l.area > 0) || !std::isfinite(l.area)) {
      dropped_.push_back(s.pointer);
      continue;
    }
    const auto index = static_cast<uint32_t>(area_.size());
    const double power = kPi * l.area * light_power_radiance(m.emission) * (m.two_sided ? 2.0 : 1.0);
    first_entry_.push_back(static_cast<uint32_t>(entries_.size()));
    tri_entry_.emplace_back();
    if (s.type == ShapeType::mesh) {
      tri_entry_.back().assign(tri_area.size(), -1);
      for (uint32_t t = 0; t < tri_area.size(); ++t) {
        if (!(tri_area[t] > 0)) continue;  // never sampled (zero weight)
        tri_entry_.back()[t] = static_cast<int32_t>(entries_.size());
        entries_.push_back({index, t, tri_area[t]});
        weights.push_back(power * (tri_area[t] / l.area));
      }
    } else {
      entries_.push_back({index, 0, l.area});
      weights.push_back(power);
    }
    light_of_shape_[i] = static_cast<int>(index);
    area_.push_back(l);
  }
  if (sky_) {
    double r = 1.0;
    const SceneBounds b = scene_bounds(scene);
    const double half_diag = b.empty() ? 0.0 : 0.5 * length(b.hi - b.lo);
    if (half_diag > 0 && std::isfinite(half_diag)) r = half_diag;
    entries_.push_back({static_cast<uint32_t>(area_.size()), 0, 0.0});
    const Rgb l = scene.environment ? scene.environment->mean_radiance() : *scene.sky;
    weights.push_back(4.0 * kPi * kPi * r * r * light_power_radiance(l));
  }
  for (double& w : weights) {
    if (!std::isfinite(w)) w = std::numeric_limits<double>::max() / static_cast<double>(weights.size() + 1);
  }
  if (!weights.empty()) {
    pick_.emplace(weights);
    // The probability of a light = the sum over its entries, as the table samples them.
    for (size_t e = 0; e < entries_.size(); ++e) {
      if (entries_[e].light < area_.size()) {
        area_[entries_[e].light].pick += pick_->pdf(e);
      } else {
        sky_pick_ += pick_->pdf(e);
      }
    }
  }
  if (selection == LightSelection::tree && emitter_entries() > 0) {
    std::vector<LightBounds> leaves(emitter_entries());
    for (size_t e = 0; e < leaves.size(); ++e) {
      const AreaLight& l = area_[entries_[e].light];
      const Shape& s = scene.shapes[l.shape];
      leaves[e] = entry_bounds(s, entries_[e].triangle, scene.materials[s.material].two_sided);
      leaves[e].phi = weights[e];
    }
    tree_.emplace(leaves);
  }
}

int64_t LightSet::entry_of(uint32_t shape, uint32_t prim) const {
  const int li = shape < light_of_shape_.size() ? light_of_shape_[shape] : -1;
  if (li < 0) return -1;
  const auto l = static_cast<size_t>(li);
  if (scene_.shapes[shape].type != ShapeType::mesh) return first_entry_[l];
  return prim < tri_entry_[l].size() ? tri_entry_[l][prim] : -1;
}

double LightSet::entry_pmf(const Vec3& x, size_t e) const {
  if (!tree_) return pick_ ? pick_->pdf(e) : 0.0;
  return (1.0 - sky_pick_) * tree_->pmf(x, static_cast<uint32_t>(e));
}

double LightSet::choice_pmf(const Vec3& x, uint32_t shape, uint32_t prim) const {
  const int64_t e = entry_of(shape, prim);
  return e < 0 ? 0.0 : entry_pmf(x, static_cast<size_t>(e));
}

double LightSet::pick_pmf(uint32_t shape) const {
  const int li = shape < light_of_shape_.size() ? light_of_shape_[shape] : -1;
  return li < 0 ? 0.0 : area_[static_cast<size_t>(li)].pick;
}

LightSample LightSet::sample(const Vec3& x, const Vec3& n, double u0, double u1, double u2) const {
  LightSample out;
  if (!pick_) return out;
  size_t chosen = 0;
  double tree_pick = 0;  // the tree's choice probability (tree selection)
  if (tree_) {
    if (sky_ && u0 < sky_pick_) {
      chosen = entries_.size() - 1;  // the sky
    } else {
      const double u = sky_ ? std::min((u0 - sky_pick_) / (1.0 - sky_pick_), std::nextafter(1.0, 0.0)) : u0;
      const std::optional<LightTree::Pick> pk = tree_->sample(x, u);
      if (!pk) return out;  // an empty tree
      chosen = pk->leaf;
      tree_pick = (1.0 - sky_pick_) * pk->pmf;
    }
  } else {
    chosen = pick_->sample(u0);
  }
  const Entry& entry = entries_[chosen];
  if (entry.light == area_.size()) {  // the sky
    const double select = sky_pick_;
    if (scene_.environment) {
      const EnvironmentMap::Sample es = scene_.environment->sample({u1, u2});
      if (!(es.pdf > 0)) return out;
      out.wi = es.wi;
      out.pdf = es.pdf * select;
      out.dist = kInf;
      out.le = es.le;
      out.sky = true;
      return out;
    }
    const Frame f = Frame::from_normal(n);
    out.wi = f.to_world(sample_cosine_hemisphere({u1, u2}));
    const double pdf = cosine_hemisphere_pdf(dot(n, out.wi));
    if (!(pdf > 0)) return out;
    out.pdf = pdf * select;
    out.dist = kInf;
    out.le = *scene_.sky;
    out.sky = true;
    return out;
  }
  const AreaLight& l = area_[entry.light];
  const double select = tree_ ? tree_pick : l.pick;
  const Shape& s = scene_.shapes[l.shape];
  double pdf_solid = 0;
  Vec2 uv{};  // texture coordinates of the light point (meshes with uvs)
  if (s.type == ShapeType::sphere && outside_sphere(s, x)) {
    const Vec3 to_c = s.center - x;
    const double dc = length(to_c);
    const double cos_max = cone_cos_max(s, x);
    pdf_solid = uniform_cone_pdf(cos_max);
    if (!(pdf_solid > 0) || !std::isfinite(pdf_solid)) return out;
    const Vec3 wi = Frame::from_normal(to_c / dc).to_world(sample_uniform_cone({u1, u2}, cos_max));
    // Nearest intersection; at the silhouette rounding may miss: use the closest point.
    const double b = dot(to_c, wi);
    const Vec3 l_perp = to_c - wi * b;
    const double disc = s.radius * s.radius - dot(l_perp, l_perp);
    const double t = b - safe_sqrt(disc);
    const Vec3 q = x + wi * t - s.center;
    const double ql = length(q);
    out.n = ql > 0 ? q / ql : -wi;
    out.p = s.center + out.n * s.radius;
    out.wi = wi;
  } else {
    double pdf_area = 1.0 / (tree_ ? entry.area : l.area);  // the tree picks a triangle, then a point on it
    switch (s.type) {
      case ShapeType::sphere: {
        out.n = sample_uniform_sphere({u1, u2});
        out.p = s.center + out.n * s.radius;
        break;
      }
      case ShapeType::disk: {
        const Vec2 d = sample_uniform_disk_concentric({u1, u2});
        const Frame f = Frame::from_normal(s.normal);
        out.p = s.center + f.t * (s.radius * d.x) + f.b * (s.radius * d.y);
        out.n = s.normal;
        break;
      }
      case ShapeType::quad: {
        out.p = s.corner + s.edge_u * u1 + s.edge_v * u2;
        out.n = normalize(cross(s.edge_u, s.edge_v));
        break;
      }
      case ShapeType::mesh: {
        const auto& tri = s.triangles[entry.triangle];
        const Vec3 &a = s.vertices[tri[0]], &b = s.vertices[tri[1]], &c = s.vertices[tri[2]];
        const TrianglePointSample ts = sample_triangle_point(a, b, c, {u1, u2});
        if (!(ts.pdf > 0)) return out;
        out.p = ts.p;
        if (!s.uvs.empty()) {
          const Vec2 &ta = s.uvs[tri[0]], &tb = s.uvs[tri[1]], &tc = s.uvs[tri[2]];
          uv = {ta.x * ts.b[0] + tb.x * ts.b[1] + tc.x * ts.b[2], ta.y * ts.b[0] + tb.y * ts.b[1] + tc.y * ts.b[2]};
        }
        const Vec3 nn = cross(b - a, c - a);
        const double len = length(nn);
        if (!(len > 0)) return out;
        out.n = nn / len;
        break;
      }
    }
    const Vec3 d = out.p - x;
    const double d2 = dot(d, d);
    if (!(d2 > 0)) return out;
    out.wi = d / std::sqrt(d2);
    const double cos_l = std::fabs(dot(out.n, out.wi));
    if (!(cos_l > kMinLightCos)) return out;  // edge-on: no sample rather than an Inf weight
    pdf_solid = pdf_area * d2 / cos_l;
  }
  out.dist = length(out.p - x);
  out.le = emitted(scene_, l.shape, out.n, -out.wi, uv);
  out.pdf = pdf_solid * select;
  if (!std::isfinite(out.pdf)) out.pdf = 0;
  return out;
}

double LightSet::pdf_hit(const Vec3& x, const Hit& hit) const {
  const int li = light_of_shape_[hit.shape];
  if (li < 0) return 0.0;
  const AreaLight& l = area_[static_cast<size_t>(li)];
  double select = l.pick, area = l.area;
  if (tree_) {
    const int64_t e = entry_of(hit.shape, hit.prim);
    if (e < 0) return 0.0;
    select = entry_pmf(x, static_cast<size_t>(e));
    area = entries_[static_cast<size_t>(e)].area;
    if (!(select > 0)) return 0.0;
  }
  const Shape& s = scene_.shapes[l.shape];
  if (s.type == ShapeType::sphere && outside_sphere(s, x)) {
    const double pdf = uniform_cone_pdf(cone_cos_max(s, x));
    return pdf > 0 && std::isfinite(pdf) ? pdf * select : 0.0;  // as sample(): no sample
  }
  return area_to_solid_angle(1.0 / area, x, hit.p, hit.n) * select;
}

double LightSet::pdf_dir(const Vec3& x, const Vec3& wi, const Hit& hit) const {
  const int li = light_of_shape_[hit.shape];
  if (li < 0) return 0.0;
  const Shape& s = scene_.shapes[hit.shape];
  // The cone density depends on the direction only.
  if (s.type == ShapeType::sphere && outside_sphere(s, x)) return pdf_hit(x, hit);
  Hit h = hit;
  if (s.type == ShapeType::sphere) {
    // Roots of |x + t wi - c| = r (stable form); take the one nearest the traced hit.
    const Vec3 f = x - s.center;
    const double b = -dot(f, wi);
    const Vec3 perp = f + wi * b;
    const double disc = s.radius * s.radius - dot(perp, perp);
    if (disc >= 0) {
      const double root = std::sqrt(disc);
      const double c = dot(f, f) - s.radius * s.radius;
      const double q = b >= 0 ? b + root : b - root;  // |q| >= |the other root|
      const double t0 = q, t1 = q != 0 ? c / q : q;   // t0 t1 = c
      const double t_ref = length(hit.p - x);
      const double t = std::fabs(t0 - t_ref) <= std::fabs(t1 - t_ref) ? t0 : t1;
      if (t > 0) {
        const Vec3 q_hit = x + wi * t - s.center;
        const double len = length(q_hit);
        if (len > 0) {
          h.n = q_hit / len;
          h.p = s.center + h.n * s.radius;
        }
      }
    }
  } else {
    // Planar (quad, disk, one triangle of a mesh): the plane of the hit, along wi from x.
    const double denom = dot(wi, hit.n);
    if (denom != 0) {
      const double t = dot(hit.p - x, hit.n) / denom;
      if (t > 0 && std::isfinite(t)) h.p = x + wi * t;
    }
  }
  return pdf_hit(x, h);
}

double LightSet::pdf_sky(const Vec3& n, const Vec3& wi) const {
  if (!sky_) return 0.0;
  if (scene_.environment) return scene_.environment->pdf(wi) * sky_pick_;
  return cosine_hemisphere_pdf(dot(n, wi)) * sky_pick_;
}

}  // namespace tally
