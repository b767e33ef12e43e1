#pragma once
// Decides, from the scene and the query, which effects a lighting job must simulate
// and switches the rest off (DESIGN.md, "Simulate only what the scene calls for").
// Rules (each is sufficient, never a heuristic that could change the answer):
//   shadows   off when no segment from a shading point to a light can be blocked: every
//             shape is convex (sphere, quad, disk, single triangle) and the shapes that
//             are neither the receiver nor the light number zero. A receiver is a shape
//             for images and a free point for point queries; point lights, directional
//             lights and the sky are not shapes, so then no other shape may exist.
//             Also off when nothing traces shadow rays (hemisphere estimators and no
//             point/directional lights).
//   indirect  off when max_depth is 1 or no shape reflects light (all albedos zero).
//   specular  off when no material is a mirror (no delta bounces can happen). Glossy
//             materials (GGX / metallic-roughness, Phong) are not delta: they need what
//             diffuse ones need (BSDF and light samples, shadow rays, indirect when
//             max_depth > 1), and the plan says so in the specular line.
//             With max_depth >= 2 and a metallic-roughness material of roughness below
//             kNarrowGlossRoughness, the line adds a caveat (not a switch): light through
//             such narrow lobes is found by BSDF sampling alone, and where few paths find
//             it, low-spp per-pixel error bars under-cover it.
//   sky       off without a sky (misses return 0 without a lookup).
//   emission  off when no shape emits (hits are not looked up for emitted radiance).
//   light_tree on when the scene has more than kLightTreeMinEmitters emitter entries
//             (light_tree.hpp; a mesh counts one per triangle) or the spec asks for it
//             ("light_selection": "tree"); off otherwise or with "power". Listed in the
//             plan only when on or asked for; "full" does not force it (both selections
//             are exact, they differ only in variance).
//   delta_light_tree  on when the scene has more than kDeltaLightTreeMinLights point and
//             spot lights (delta_light_tree.hpp) or the spec asks for "tree": next-event
//             estimation then picks one of them per vertex from a light tree; off (each
//             one added at every vertex, the exact loop) otherwise or with "power".
//             Listed whenever the scene has point or spot lights; "full" does not force it.
// "plan": "full" forces every effect on: the tests compare both.
#include <optional>
#include <string>
#include <vector>

#include "common/lighting/bsdf.hpp"
#include "common/lighting/delta_light_tree.hpp"
#include "common/lighting/light_tree.hpp"
#include "common/lighting/scene.hpp"

namespace tally {

// Roughness (glTF's perceptual) under which the plan's specular line warns that light
// through the lobe is found by BSDF sampling alone (the suite's glossy scene: coverage
// 0.70 at 16 spp with metals at 0.08-0.25, 0.91 with all at 0.7; docs/lighting.md).
inline constexpr double kNarrowGlossRoughness = 0.3;

struct PlanEffect {
  std::string name;
  bool on = true;
  std::string why;
};

struct Plan {
  bool full = false;
  bool shadows = true;
  bool indirect = true;
  bool specular = true;
  bool sky = true;
  bool emission = true;
  bool light_tree = false;  // choose area lights by the light tree (light_set.hpp)
  bool delta_light_tree = false;  // pick one point/spot light per vertex (delta_light_tree.hpp)
  std::vector<PlanEffect> effects;
};

struct PlanQuery {
  bool image = false;
  int max_depth = 1;
  std::vector<Strategy> strategies;
  std::vector<uint32_t> point_materials;  // materials of the query points
  std::optional<LightSelection> light_selection;  // the spec's "light_selection" unless "auto"
};

Plan make_plan(const Scene& scene, const PlanQuery& query, bool full);

}  // namespace tally
