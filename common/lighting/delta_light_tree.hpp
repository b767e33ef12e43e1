#pragma once
// Many point and spot lights (issue 29): a light hierarchy (light_tree.hpp) over the
// scene's point and spot lights, so that next-event estimation picks ONE of them per
// shading point, with probability pmf(p, light), instead of adding every one (one
// shadow ray each). The planner switches it on (planner.hpp, delta_light_tree) above
// kDeltaLightTreeMinLights such lights; below, every delta light is still added at every
// vertex, bit for bit as before.
//
// Leaf bounds (pbrt-v4's PointLight::Bounds / SpotLight::Bounds), with Y(I) the luminance
// light_power_radiance gives the area lights' powers (light_set.hpp):
//   point  a degenerate box at its position; phi = 4 pi Y(I); the cone: all directions
//          (theta_o = pi), theta_e = pi / 2;
//   spot   the same box; axis = its direction, theta_o = the inner cone angle,
//          theta_e = outer - inner + kSpotConeSlack (the falloff is 0 beyond the outer
//          cone; the slack keeps rounding from giving a lit point importance 0);
//          phi = 2 pi Y(I) (1 - (cos_inner + cos_outer) / 2) (pbrt-v4's SpotLight::Phi).
// The powers only shape the pmf (variance), never the answer: a light with phi > 0 that
// can light p has pmf > 0 there. Lights with phi = 0 (black) are never picked; they send
// nothing. Directional lights have no position: they stay outside the tree and are
// always added.
//
// A delta light cannot be hit by a BSDF ray, so nothing but the sampler itself needs the
// pmf; pmf(p, light) is still bit for bit what sample() reports (LightTree's guarantee),
// so tests can check the distribution exactly. Immutable after construction; shared by
// every thread of the job.
#include <cstddef>
#include <cstdint>
#include <optional>
#include <vector>

#include "common/lighting/light_tree.hpp"
#include "common/lighting/scene.hpp"

namespace tally {

// The planner samples point and spot lights through the tree when a scene has more
// than this many of them: below it, adding each (one shadow ray per light per vertex)
// costs little and has no selection noise.
inline constexpr size_t kDeltaLightTreeMinLights = 64;

// Point and spot lights of the scene (the ones with a position).
size_t positioned_light_count(const Scene& scene);

// The tree's leaf bounds of a point or spot light.
LightBounds delta_light_bounds(const DeltaLight& light);

class DeltaLightTree {
 public:
  explicit DeltaLightTree(const Scene& scene);

  struct Pick {
    uint32_t light = 0;  // index into scene.delta_lights
    double pmf = 0.0;
  };
  // One point or spot light for the shading point p, u in [0, 1); nullopt when the
  // scene has none with power > 0.
  std::optional<Pick> sample(const Vec3& p, double u) const;
  // The probability that sample(p, .) picks scene.delta_lights[light] (0 for
  // directional and powerless lights).
  double pmf(const Vec3& p, uint32_t light) const;
  // The directional lights (indices into scene.delta_lights): added at every vertex.
  const std::vector<uint32_t>& directional() const { return directional_; }
  size_t leaves() const { return light_of_leaf_.size(); }

 private:
  std::vector<uint32_t> light_of_leaf_;
  std::vector<int64_t> leaf_of_light_;  // -1: directional
  std::vector<uint32_t> directional_;
  LightTree tree_;
};

}  // namespace tally
