#pragma once
// Self-intersection-free ray origins: Wächter & Binder, "A Fast and Robust Method for
// Avoiding Self-Intersection" (Ray Tracing Gems, ch. 6). Embree traces in float, so the
// origin is rounded to float and then moved off the surface by a few float ulps along
// the normal (integer steps on the bit pattern), which bounds the rounding error of the
// hit point at any magnitude; near the origin, where ulps are tiny, a fixed epsilon is
// used instead. The scene is centred on its bounds first (scene.hpp), so coordinates
// stay small even for scenes placed far from the world origin.
#include <bit>
#include <cmath>
#include <cstdint>

#include "common/math/vec3.hpp"

namespace tally {

inline float offset_coordinate(float p, float n) {
  constexpr float kOrigin = 1.0f / 32.0f;
  constexpr float kFloatScale = 1.0f / 65536.0f;
  constexpr float kIntScale = 256.0f;
  const auto of_i = static_cast<int32_t>(kIntScale * n);
  const int32_t bits = std::bit_cast<int32_t>(p);
  const float p_i = std::bit_cast<float>(bits + (p < 0 ? -of_i : of_i));
  return std::fabs(p) < kOrigin ? p + kFloatScale * n : p_i;
}

// `p` a point on a surface, `n` the unit normal on the side the new ray leaves from.
// The result holds float-representable coordinates.
inline Vec3 offset_ray_origin(const Vec3& p, const Vec3& n) {
  return {static_cast<double>(offset_coordinate(static_cast<float>(p.x), static_cast<float>(n.x))),
          static_cast<double>(offset_coordinate(static_cast<float>(p.y), static_cast<float>(n.y))),
          static_cast<double>(offset_coordinate(static_cast<float>(p.z), static_cast<float>(n.z)))};
}

}  // namespace tally
