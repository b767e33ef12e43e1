#pragma once
// The frame of the production-frame tests and benchmark (issue 28: tests/lighting/
// state_limit_test, tests/e2e/frames_e2e_test, bench/frame_memory_bench): a 6 x 6 diffuse
// floor at z = 0 lit by a 1 x 1 emitter at z = 2 facing down, seen from (0, -4.5, 3.2);
// an image query of w x h pixels, `mis`, direct light only (max_depth 1), the default
// sobol sampler (an image's default K = 4 replicates), stopping at `spp` samples a pixel.
#include <cstdint>
#include <nlohmann/json.hpp>

namespace tally::scenes {

inline nlohmann::json frame_spec(int w, int h, uint64_t spp) {
  nlohmann::json spec = nlohmann::json::parse(R"({
    "kind": "lighting", "seed": 7,
    "scene": {
      "camera": {"position": [0, -4.5, 3.2], "look_at": [0, 0, 0.6], "up": [0, 0, 1], "fov_deg": 50},
      "materials": {"white": {"type": "diffuse", "albedo": [0.8, 0.8, 0.8]},
                    "lamp": {"type": "emissive", "radiance": [5, 5, 5]}},
      "shapes": [
        {"type": "quad", "corner": [-3, -3, 0], "edge_u": [6, 0, 0], "edge_v": [0, 6, 0], "material": "white"},
        {"type": "quad", "corner": [-0.5, -0.5, 2], "edge_u": [0, 1, 0], "edge_v": [1, 0, 0], "material": "lamp"}]
    },
    "query": {"type": "image", "max_depth": 1}, "estimators": ["mis"]
  })");
  spec["scene"]["camera"]["resolution"] = {w, h};
  spec["stop"] = {{"max_samples", spp}};
  return spec;
}

}  // namespace tally::scenes
