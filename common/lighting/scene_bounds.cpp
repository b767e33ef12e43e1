#include "common/lighting/scene_bounds.hpp"

#include <algorithm>
#include <limits>

namespace tally {

SceneBounds scene_bounds(const Scene& scene) {
  constexpr double inf = std::numeric_limits<double>::infinity();
  SceneBounds b{{inf, inf, inf}, {-inf, -inf, -inf}};
  auto grow = [&](const Vec3& p, double r) {
    b.lo = {std::min(b.lo.x, p.x - r), std::min(b.lo.y, p.y - r), std::min(b.lo.z, p.z - r)};
    b.hi = {std::max(b.hi.x, p.x + r), std::max(b.hi.y, p.y + r), std::max(b.hi.z, p.z + r)};
  };
  for (const Shape& s : scene.shapes) {
    for (const Vec3& v : s.vertices) grow(v, 0.0);
    if (s.type == ShapeType::sphere || s.type == ShapeType::disk) grow(s.center, s.radius);
  }
  return b;
}

}  // namespace tally
