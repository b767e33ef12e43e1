#pragma once
// The many-light scene (issue 29): a closed 12 x 3 x 12 room with diffuse walls, a row
// of diffuse pillars, and `n` small emissive squares (side 0.05, radiance 20..100)
// spread through the upper half of the room at deterministic pseudo-random positions
// and orientations, so that most emitters are far from any one shading point. Written
// here, nothing downloaded: `lighting_bench --many-lights-scene FILE` saves it as a
// lighting job spec; the bench and tests/lighting/light_tree_test.cpp render it.
// many_point_lights_scene: the same room lit by point and spot lights instead
// (bench/lighting_bench.cpp --many-point-lights, tests/lighting/delta_light_tree_test.cpp).
#include <cmath>
#include <cstdint>
#include <nlohmann/json.hpp>

#include "common/math/vec3.hpp"
#include "common/rng/counter_rng.hpp"
#include "common/sampling/safe_math.hpp"

namespace tally::scenes {

inline nlohmann::json many_lights_scene(int n, uint64_t seed = 1) {
  using json = nlohmann::json;
  auto v = [](const Vec3& a) { return json::array({a.x, a.y, a.z}); };
  json shapes = json::array();
  auto quad = [&](Vec3 c, Vec3 eu, Vec3 ev, const json& m) {
    shapes.push_back({{"type", "quad"}, {"corner", v(c)}, {"edge_u", v(eu)}, {"edge_v", v(ev)}, {"material", m}});
  };
  const json wall = {{"type", "diffuse"}, {"albedo", {0.6, 0.6, 0.6}}};
  const double h = 6.0, y = 3.0;
  quad({-h, 0, -h}, {0, 0, 2 * h}, {2 * h, 0, 0}, wall);  // floor, normal +y
  quad({-h, y, -h}, {2 * h, 0, 0}, {0, 0, 2 * h}, wall);  // ceiling, normal -y
  quad({-h, 0, -h}, {2 * h, 0, 0}, {0, y, 0}, wall);      // z = -h, normal +z
  quad({-h, 0, h}, {0, y, 0}, {2 * h, 0, 0}, wall);       // z = +h, normal -z
  quad({-h, 0, -h}, {0, y, 0}, {0, 0, 2 * h}, wall);      // x = -h, normal +x
  quad({h, 0, -h}, {0, 0, 2 * h}, {0, y, 0}, wall);       // x = +h, normal -x
  for (int i = -2; i <= 2; ++i) {  // pillars (spheres) along the x axis
    shapes.push_back({{"type", "sphere"}, {"center", {2.0 * i, 0.6, 0.0}}, {"radius", 0.5}, {"material", wall}});
  }
  const double s = 0.05;
  for (int k = 0; k < n; ++k) {
    const SampleRng rng(seed, static_cast<uint64_t>(k));
    const Vec3 c{-h + 0.2 + (2 * h - 0.4) * rng.uniform(0), 1.5 + 1.4 * rng.uniform(1), -h + 0.2 + (2 * h - 0.4) * rng.uniform(2)};
    // A normal in the lower hemisphere (cos uniform in [0.2, 1] towards -y).
    const double cz = 0.2 + 0.8 * rng.uniform(3), phi = 2 * kPi * rng.uniform(4), sz = std::sqrt(1 - cz * cz);
    const Vec3 nrm{sz * std::cos(phi), -cz, sz * std::sin(phi)};
    const Vec3 t = normalize(std::fabs(nrm.x) < 0.9 ? cross(nrm, Vec3{1, 0, 0}) : cross(nrm, Vec3{0, 0, 1}));
    const Vec3 b = cross(nrm, t);  // t x b = n
    const double L = 20.0 + 20.0 * (k % 5);
    quad(c - (t + b) * (0.5 * s), t * s, b * s, json{{"type", "emissive"}, {"radiance", {L, L, L}}});
  }
  return {{"shapes", shapes}};
}

// The same room with `n` point lights instead of the emissive squares (issue 29, point
// lights in the light tree): same positions, intensity 0.02..0.1 (W/sr-like, so the
// floor gets about what the squares give it), every fifth one a spot light (outer cone
// 50 degrees, inner 20) pointing at the floor with the square's tilt.
inline nlohmann::json many_point_lights_scene(int n, uint64_t seed = 1) {
  using json = nlohmann::json;
  json scene = many_lights_scene(0, seed);
  json lights = json::array();
  const double h = 6.0;
  for (int k = 0; k < n; ++k) {
    const SampleRng rng(seed, static_cast<uint64_t>(k));
    const Vec3 c{-h + 0.2 + (2 * h - 0.4) * rng.uniform(0), 1.5 + 1.4 * rng.uniform(1), -h + 0.2 + (2 * h - 0.4) * rng.uniform(2)};
    const double cz = 0.2 + 0.8 * rng.uniform(3), phi = 2 * kPi * rng.uniform(4), sz = std::sqrt(1 - cz * cz);
    const double I = 0.02 + 0.02 * (k % 5);
    json l = {{"position", {c.x, c.y, c.z}}, {"intensity", {I, I, I}}};
    if (k % 5 == 4) {
      l["type"] = "spot";
      l["direction"] = {sz * std::cos(phi), -cz, sz * std::sin(phi)};
      l["outer_cone_deg"] = 50;
      l["inner_cone_deg"] = 20;
    } else {
      l["type"] = "point";
    }
    lights.push_back(l);
  }
  scene["lights"] = lights;
  return scene;
}

}  // namespace tally::scenes
