#include "common/lighting/delta_light_tree.hpp"

#include <algorithm>
#include <cmath>

#include "common/lighting/light_set.hpp"
#include "common/sampling/safe_math.hpp"

namespace tally {

namespace {

// Widens a spot light's emission spread (radians) past its outer cone. cos(x) rounds to
// 1 for x below ~1.5e-8, so the slack must be larger than that to keep cos_e < 1.
constexpr double kSpotConeSlack = 1e-6;

bool positioned(const DeltaLight& l) { return l.type == DeltaLightType::point || l.type == DeltaLightType::spot; }

std::vector<LightBounds> leaf_bounds(const Scene& scene, const std::vector<uint32_t>& light_of_leaf) {
  std::vector<LightBounds> b;
  b.reserve(light_of_leaf.size());
  for (uint32_t i : light_of_leaf) b.push_back(delta_light_bounds(scene.delta_lights[i]));
  return b;
}

std::vector<uint32_t> positioned_lights(const Scene& scene) {
  std::vector<uint32_t> out;
  for (uint32_t i = 0; i < scene.delta_lights.size(); ++i) {
    if (positioned(scene.delta_lights[i])) out.push_back(i);
  }
  return out;
}

}  // namespace

size_t positioned_light_count(const Scene& scene) {
  return static_cast<size_t>(std::count_if(scene.delta_lights.begin(), scene.delta_lights.end(), positioned));
}

LightBounds delta_light_bounds(const DeltaLight& l) {
  LightBounds b;
  b.lo = l.position;
  b.hi = l.position;
  const double y = light_power_radiance(l.intensity);
  if (l.type == DeltaLightType::spot) {
    // An inner cone wider than the outer one (not accepted by the readers) would mean
    // full intensity up to the outer cone: take the outer one then.
    const double cos_inner = std::max(l.cos_inner, l.cos_outer);
    const double theta_inner = std::acos(std::clamp(cos_inner, -1.0, 1.0));
    const double theta_outer = std::acos(std::clamp(l.cos_outer, -1.0, 1.0));
    b.w = l.direction;
    b.cos_o = std::cos(theta_inner);
    b.cos_e = std::cos(std::min(theta_outer - theta_inner + kSpotConeSlack, kPi));
    b.phi = 2 * kPi * y * (1.0 - 0.5 * (cos_inner + l.cos_outer));
  } else {
    b.cos_o = -1.0;  // all directions
    b.cos_e = 0.0;   // cos(pi / 2)
    b.phi = 4 * kPi * y;
  }
  if (!(b.phi > 0) || !std::isfinite(b.phi)) b.phi = 0.0;
  return b;
}

DeltaLightTree::DeltaLightTree(const Scene& scene)
    : light_of_leaf_(positioned_lights(scene)),
      leaf_of_light_(scene.delta_lights.size(), -1),
      tree_(leaf_bounds(scene, light_of_leaf_)) {
  for (size_t k = 0; k < light_of_leaf_.size(); ++k) leaf_of_light_[light_of_leaf_[k]] = static_cast<int64_t>(k);
  for (uint32_t i = 0; i < scene.delta_lights.size(); ++i) {
    if (!positioned(scene.delta_lights[i])) directional_.push_back(i);
  }
}

std::optional<DeltaLightTree::Pick> DeltaLightTree::sample(const Vec3& p, double u) const {
  const std::optional<LightTree::Pick> pk = tree_.sample(p, u);
  if (!pk) return std::nullopt;
  return Pick{light_of_leaf_[pk->leaf], pk->pmf};
}

double DeltaLightTree::pmf(const Vec3& p, uint32_t light) const {
  if (light >= leaf_of_light_.size() || leaf_of_light_[light] < 0) return 0.0;
  return tree_.pmf(p, static_cast<uint32_t>(leaf_of_light_[light]));
}

}  // namespace tally
