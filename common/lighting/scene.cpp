#include "common/lighting/scene.hpp"

#include "common/lighting/environment_map.hpp"

namespace tally {

uint64_t Scene::resident_bytes() const {
  uint64_t b = texture_bytes;
  for (const Shape& s : shapes) {
    b += 40 * static_cast<uint64_t>(s.vertices.size()) + 112 * static_cast<uint64_t>(s.triangles.size()) +
         24 * static_cast<uint64_t>(s.normals.size()) + 16 * static_cast<uint64_t>(s.uvs.size());
  }
  if (environment) {
    b += kEnvironmentTexelBytes * static_cast<uint64_t>(environment->width()) *
         static_cast<uint64_t>(environment->height());
  }
  return b;
}

}  // namespace tally
