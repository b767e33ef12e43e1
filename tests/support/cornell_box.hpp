#pragma once
// The Cornell box of the lighting tests and benchmarks (tests/lighting/determinism_test,
// bench/lighting_bench, bench/sampler_bench): a 2 x 2 x 2 room open towards +z with a
// white floor, ceiling and back wall, a red left and a green right wall, a square lamp
// under the ceiling and a sphere; the camera looks in from z = 3.5.
#include <nlohmann/json.hpp>

namespace tally::scenes {

inline nlohmann::json cornell_diffuse(double r, double g, double b) {
  return {{"type", "diffuse"}, {"albedo", {r, g, b}}};
}

// "white", "red", "green" and "lamp" (radiance 12).
inline nlohmann::json cornell_materials() {
  return {{"white", cornell_diffuse(0.75, 0.75, 0.75)},
          {"red", cornell_diffuse(0.7, 0.1, 0.1)},
          {"green", cornell_diffuse(0.1, 0.7, 0.1)},
          {"lamp", {{"type", "emissive"}, {"radiance", {12, 12, 12}}}}};
}

// The five walls, the lamp and the sphere, made of `sphere_material` (a name or a material).
inline nlohmann::json cornell_shapes(const nlohmann::json& sphere_material) {
  using nlohmann::json;
  return json::array({
      {{"type", "quad"}, {"corner", {-1, 0, -1}}, {"edge_u", {0, 0, 2}}, {"edge_v", {2, 0, 0}}, {"material", "white"}},
      {{"type", "quad"}, {"corner", {-1, 2, -1}}, {"edge_u", {2, 0, 0}}, {"edge_v", {0, 0, 2}}, {"material", "white"}},
      {{"type", "quad"}, {"corner", {-1, 0, -1}}, {"edge_u", {2, 0, 0}}, {"edge_v", {0, 2, 0}}, {"material", "white"}},
      {{"type", "quad"}, {"corner", {-1, 0, -1}}, {"edge_u", {0, 2, 0}}, {"edge_v", {0, 0, 2}}, {"material", "red"}},
      {{"type", "quad"}, {"corner", {1, 0, -1}}, {"edge_u", {0, 0, 2}}, {"edge_v", {0, 2, 0}}, {"material", "green"}},
      {{"type", "quad"}, {"corner", {-0.25, 1.99, -0.25}}, {"edge_u", {0.5, 0, 0}}, {"edge_v", {0, 0, 0.5}}, {"material", "lamp"}},
      {{"type", "sphere"}, {"center", {-0.4, 0.35, -0.3}}, {"radius", 0.35}, {"material", sphere_material}},
  });
}

inline nlohmann::json cornell_camera() { return {{"position", {0, 1, 3.5}}, {"look_at", {0, 1, 0}}, {"fov_deg", 40}}; }

}  // namespace tally::scenes
