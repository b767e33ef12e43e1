#include "common/lighting/light_tree.hpp"

#include <algorithm>
#include <cmath>

#include "common/sampling/safe_math.hpp"

namespace tally {

namespace {

// cos(a - b) and sin(a - b) clamped at a - b >= 0 (pbrt-v4's cosSubClamped / sinSubClamped).
double cos_sub_clamped(double sin_a, double cos_a, double sin_b, double cos_b) {
  if (cos_a > cos_b) return 1.0;
  return cos_a * cos_b + sin_a * sin_b;
}
double sin_sub_clamped(double sin_a, double cos_a, double sin_b, double cos_b) {
  if (cos_a > cos_b) return 0.0;
  return sin_a * cos_b - cos_a * sin_b;
}

// Widens cones by this much (radians) when they are merged, so rounding never makes a
// merged cone miss a direction one of its parts holds.
constexpr double kConeSlack = 1e-9;

}  // namespace

LightTree::Importance LightTree::prepare(const LightBounds& b) {
  Importance m;
  m.centre = (b.lo + b.hi) * 0.5;
  m.radius = 0.5 * length(b.hi - b.lo);
  m.radius2 = m.radius * m.radius;
  m.phi = b.phi;
  m.w = b.w;
  m.cos_o = b.cos_o;
  m.sin_o = safe_sqrt(1.0 - b.cos_o * b.cos_o);
  m.cos_e = b.cos_e;
  m.two_sided = b.two_sided;
  return m;
}

double LightTree::importance(const Importance& b, const Vec3& p) {
  if (!(b.phi > 0)) return 0.0;
  const Vec3 to_p = p - b.centre;
  const double dist2 = dot(to_p, to_p);
  const double d2 = std::max(dist2, b.radius);  // pbrt-v4: max(d^2, |diagonal| / 2)
  // The angle theta_b the bounding sphere subtends at p (all directions from inside).
  double cos_b = -1.0;
  if (dist2 > b.radius2) cos_b = safe_sqrt(1.0 - b.radius2 / dist2);
  const double sin_b = safe_sqrt(1.0 - cos_b * cos_b);
  // theta_w: between the cone's axis and the direction from the centre to p.
  double cos_w = 1.0;
  if (dist2 > 0) cos_w = dot(b.w, to_p) / std::sqrt(dist2);
  if (b.two_sided) cos_w = std::fabs(cos_w);
  cos_w = std::clamp(cos_w, -1.0, 1.0);
  const double sin_w = safe_sqrt(1.0 - cos_w * cos_w);
  const double cos_x = cos_sub_clamped(sin_w, cos_w, b.sin_o, b.cos_o);
  const double sin_x = sin_sub_clamped(sin_w, cos_w, b.sin_o, b.cos_o);
  const double cos_p = cos_sub_clamped(sin_x, cos_x, sin_b, cos_b);
  if (cos_p <= b.cos_e) return 0.0;
  const double importance = b.phi * cos_p / d2;
  return std::isfinite(importance) && importance > 0 ? importance : 0.0;
}

double light_importance(const LightBounds& b, const Vec3& p) {
  return LightTree::importance(LightTree::prepare(b), p);
}

LightBounds merge_light_bounds(const LightBounds& a, const LightBounds& b) {
  if (!(a.phi > 0)) return b;
  if (!(b.phi > 0)) return a;
  LightBounds m;
  m.lo = {std::min(a.lo.x, b.lo.x), std::min(a.lo.y, b.lo.y), std::min(a.lo.z, b.lo.z)};
  m.hi = {std::max(a.hi.x, b.hi.x), std::max(a.hi.y, b.hi.y), std::max(a.hi.z, b.hi.z)};
  m.phi = a.phi + b.phi;
  m.cos_e = std::min(a.cos_e, b.cos_e);
  m.two_sided = a.two_sided || b.two_sided;
  // pbrt-v4's DirectionCone Union.
  const double theta_a = std::acos(std::clamp(a.cos_o, -1.0, 1.0));
  const double theta_b = std::acos(std::clamp(b.cos_o, -1.0, 1.0));
  const double theta_d = std::acos(std::clamp(dot(a.w, b.w), -1.0, 1.0));
  if (std::min(theta_d + theta_b, kPi) <= theta_a) {
    m.w = a.w;
    m.cos_o = a.cos_o;
  } else if (std::min(theta_d + theta_a, kPi) <= theta_b) {
    m.w = b.w;
    m.cos_o = b.cos_o;
  } else {
    const double theta_o = 0.5 * (theta_a + theta_d + theta_b) + kConeSlack;
    const Vec3 wr = cross(a.w, b.w);
    const double lr = length(wr);
    if (theta_o >= kPi || !(lr > 0)) {
      m.w = a.w;
      m.cos_o = -1.0;  // the entire sphere
    } else {
      // Rotate a.w by theta_r = theta_o - theta_a about wr (Rodrigues; wr is normal to a.w).
      const double theta_r = theta_o - theta_a;
      const Vec3 k = wr / lr;
      m.w = normalize(a.w * std::cos(theta_r) + cross(k, a.w) * std::sin(theta_r));
      m.cos_o = std::cos(theta_o);
    }
  }
  return m;
}

LightTree::LightTree(const std::vector<LightBounds>& leaves) : node_of_leaf_(leaves.size(), -1) {
  std::vector<uint32_t> ids;
  for (uint32_t i = 0; i < leaves.size(); ++i) {
    if (leaves[i].phi > 0) ids.push_back(i);
  }
  if (ids.empty()) return;
  nodes_.reserve(2 * ids.size());
  root_ = build(ids, 0, ids.size(), leaves, -1);
  importance_.reserve(nodes_.size());
  for (const Node& n : nodes_) importance_.push_back(prepare(n.b));
}

int32_t LightTree::build(std::vector<uint32_t>& ids, size_t begin, size_t end, const std::vector<LightBounds>& leaves,
                         int32_t parent) {
  const auto index = static_cast<int32_t>(nodes_.size());
  nodes_.emplace_back();
  nodes_[static_cast<size_t>(index)].parent = parent;
  if (end - begin == 1) {
    Node& n = nodes_[static_cast<size_t>(index)];
    n.b = leaves[ids[begin]];
    n.leaf = ids[begin];
    node_of_leaf_[ids[begin]] = index;
    return index;
  }
  // The longest axis of the centroids' bounds; split at the median centroid (ties by index).
  Vec3 lo{HUGE_VAL, HUGE_VAL, HUGE_VAL}, hi{-HUGE_VAL, -HUGE_VAL, -HUGE_VAL};
  auto centre = [&](uint32_t i) { return (leaves[i].lo + leaves[i].hi) * 0.5; };
  for (size_t i = begin; i < end; ++i) {
    const Vec3 c = centre(ids[i]);
    lo = {std::min(lo.x, c.x), std::min(lo.y, c.y), std::min(lo.z, c.z)};
    hi = {std::max(hi.x, c.x), std::max(hi.y, c.y), std::max(hi.z, c.z)};
  }
  const Vec3 ext = hi - lo;
  const int axis = ext.x >= ext.y && ext.x >= ext.z ? 0 : (ext.y >= ext.z ? 1 : 2);
  auto coord = [&](uint32_t i) {
    const Vec3 c = centre(i);
    return axis == 0 ? c.x : (axis == 1 ? c.y : c.z);
  };
  const size_t mid = begin + (end - begin) / 2;
  std::nth_element(ids.begin() + static_cast<std::ptrdiff_t>(begin), ids.begin() + static_cast<std::ptrdiff_t>(mid),
                   ids.begin() + static_cast<std::ptrdiff_t>(end), [&](uint32_t a, uint32_t b) {
                     const double ca = coord(a), cb = coord(b);
                     return ca < cb || (ca == cb && a < b);
                   });
  const int32_t left = build(ids, begin, mid, leaves, index);
  const int32_t right = build(ids, mid, end, leaves, index);
  Node& n = nodes_[static_cast<size_t>(index)];
  n.left = left;
  n.right = right;
  n.b = merge_light_bounds(nodes_[static_cast<size_t>(left)].b, nodes_[static_cast<size_t>(right)].b);
  return index;
}

double LightTree::left_probability(const Node& n, const Vec3& p) const {
  const Importance& l = importance_[static_cast<size_t>(n.left)];
  const Importance& r = importance_[static_cast<size_t>(n.right)];
  const double il = importance(l, p);
  const double ir = importance(r, p);
  if (il + ir > 0) return il / (il + ir);
  // Neither child can light p (the parent's looser bound let the walk get here): go by
  // power, so the pmf stays a distribution over all leaves (the sample is wasted, as
  // pbrt's "no sample" would be, never biased).
  return l.phi / (l.phi + r.phi);
}

std::optional<LightTree::Pick> LightTree::sample(const Vec3& p, double u) const {
  if (root_ < 0) return std::nullopt;
  int32_t at = root_;
  double pmf = 1.0;
  while (nodes_[static_cast<size_t>(at)].left >= 0) {
    const Node& n = nodes_[static_cast<size_t>(at)];
    const double pl = left_probability(n, p);
    if (u < pl) {
      u = std::min(u / pl, std::nextafter(1.0, 0.0));
      pmf *= pl;
      at = n.left;
    } else {
      u = std::min((u - pl) / (1.0 - pl), std::nextafter(1.0, 0.0));
      pmf *= 1.0 - pl;
      at = n.right;
    }
  }
  return Pick{nodes_[static_cast<size_t>(at)].leaf, pmf};
}

double LightTree::pmf(const Vec3& p, uint32_t leaf) const {
  if (leaf >= node_of_leaf_.size() || node_of_leaf_[leaf] < 0) return 0.0;
  // The path from the root, then the same products in the same order as sample().
  int32_t path[64];
  int depth = 0;
  for (int32_t at = node_of_leaf_[leaf]; at >= 0 && depth < 64; at = nodes_[static_cast<size_t>(at)].parent) {
    path[depth++] = at;
  }
  double pmf = 1.0;
  for (int k = depth - 1; k > 0; --k) {
    const Node& n = nodes_[static_cast<size_t>(path[k])];
    const double pl = left_probability(n, p);
    pmf *= n.left == path[k - 1] ? pl : 1.0 - pl;
  }
  return pmf;
}

}  // namespace tally
