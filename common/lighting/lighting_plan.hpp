#pragma once
// What a lighting job plans to run and what it found, as typed structs: the job
// (lighting_job.hpp) fills them; common/protocol/lighting_json.cpp writes them as JSON
// (docs/lighting.md). Optional fields not set are absent from the JSON.
#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "common/engine/kernel.hpp"
#include "common/lighting/image_kernel.hpp"
#include "common/lighting/planner.hpp"
#include "common/math/vec3.hpp"

namespace tally {

struct LightingScenePlan {
  uint64_t shapes = 0;
  uint64_t triangles = 0;
  uint64_t sampled_lights = 0;
  uint64_t delta_lights = 0;
  std::vector<std::string> dropped_zero_area_lights;
  Vec3 local_origin;
  uint64_t textures = 0;       // image textures the materials use
  uint64_t texture_bytes = 0;  // their decoded texels (JobLimits::max_texture_bytes caps it)
};

struct LightingImagePlan {
  int width = 0, height = 0, tile_size = 0;
  uint32_t tiles = 0;
};

struct LightingPlan {
  bool image = false;  // query "image", else "points"
  std::vector<std::string> estimators;
  int max_depth = 1;
  bool russian_roulette = false;
  bool full = false;                // "plan": "full" (every effect forced on)
  std::vector<PlanEffect> effects;  // what is on, what is off, and why
  std::string sampler;              // "sobol" | "independent"
  uint32_t replicates = 1;
  std::string error_bars;
  LightingScenePlan scene;
  uint64_t channels = 0;
  std::string channel_layout;
  PassSchedule pass_schedule;
  std::optional<uint64_t> points;           // point queries
  std::optional<LightingImagePlan> image_size;  // image queries ...
  std::optional<std::string> error_summary;
  std::optional<AdaptiveSettings> adaptive;  // ... with adaptive sampling
};

// One estimator at one point: RGB estimates, their errors and its efficiency.
struct PointEstimate {
  std::string estimator;
  std::array<double, 3> mean{}, std_error{}, variance{}, ci_lo{}, ci_hi{};
  uint64_t samples = 0;
  double seconds_per_sample = 0.0;
  std::optional<double> efficiency;  // 1 / (sigma^2 t); unknown without variance or time
};

struct PointResult {
  uint64_t index = 0;
  Vec3 p;
  std::vector<PointEstimate> estimates;  // in the order of the job's estimators
};

struct LightingImageResult {
  int width = 0, height = 0, tile_size = 0;
  uint32_t tiles = 0;
  uint64_t spp_min = 0, spp_max = 0;
  double mean_abs_error = 0.0, mean_rel_error = 0.0;
};

struct LightingResult {
  std::optional<std::vector<PointResult>> points;  // point queries
  std::optional<LightingImageResult> image;        // image queries
};

inline constexpr const char* kPointChannelLayout =
    "(((estimator * points) + point) * replicates + replicate) * 3 + rgb";
inline constexpr const char* kImageChannelLayout =
    "tile-major; pixels row-major within a tile; replicate-major then rgb within a pixel";

}  // namespace tally
