#include "common/lighting/localize_scene.hpp"

#include "common/lighting/scene_bounds.hpp"

namespace tally {

void localize_scene(Scene& scene) {
  const SceneBounds b = scene_bounds(scene);
  const Vec3 origin = b.empty() ? Vec3{} : (b.lo + b.hi) * 0.5;
  scene.origin = origin;
  auto round_f = [](const Vec3& v) {
    return Vec3{static_cast<double>(static_cast<float>(v.x)), static_cast<double>(static_cast<float>(v.y)),
                static_cast<double>(static_cast<float>(v.z))};
  };
  for (Shape& s : scene.shapes) {
    for (Vec3& v : s.vertices) v = round_f(v - origin);
    s.center = round_f(s.center - origin);
    s.radius = static_cast<double>(static_cast<float>(s.radius));
    if (s.type == ShapeType::quad) {
      s.corner = s.vertices[0];
      s.edge_u = s.vertices[1] - s.vertices[0];
      s.edge_v = s.vertices[3] - s.vertices[0];
    }
  }
  for (DeltaLight& l : scene.delta_lights) {
    if (l.type != DeltaLightType::directional) l.position = l.position - origin;
  }
  if (scene.camera) {
    scene.camera->position = scene.camera->position - origin;
    scene.camera->look_at = scene.camera->look_at - origin;
  }
}

}  // namespace tally
