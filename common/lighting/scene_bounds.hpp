#pragma once
// Axis-aligned bounds of a scene's shapes: used to localize the scene (scene_json)
// and for the sky's power (light_set). Geometry only, no spec reading.
#include "common/lighting/scene.hpp"

namespace tally {

// Axis-aligned bounds of every shape (vertices, sphere and disk extents); empty when
// lo.x > hi.x (a scene without shapes).
struct SceneBounds {
  Vec3 lo, hi;
  bool empty() const { return lo.x > hi.x; }
};
SceneBounds scene_bounds(const Scene& scene);

}  // namespace tally
