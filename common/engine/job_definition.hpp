#pragma once
// What a validated job spec compiles to. The server, the CLI and the study only talk
// to jobs through this interface and JobRunner; each job kind (integrate, lighting)
// implements it in its own area.
#include <cstdint>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <string_view>

#include "common/engine/image_source.hpp"
#include "common/engine/job_runner.hpp"
#include "common/engine/kernel.hpp"
#include "common/engine/stop_rule.hpp"

namespace tally {

// Hard limits on what one job may ask for, configured by whoever runs jobs. A spec
// over a limit is refused up front (SpecError naming the field), never half-run.
struct JobLimits {
  size_t max_dimensions = 64;
  size_t max_channels = size_t{1} << 24;
  uint64_t max_samples = 100'000'000'000ULL;
  double max_seconds = 3600.0;
  size_t max_expression_length = 4096;
  uint64_t max_pixels = 4096ULL * 4096ULL;
  uint64_t max_quadrature_points = 1ULL << 26;
  size_t max_table_size = 1 << 20;  // tabulated densities, inline meshes
  std::string asset_dir;            // OBJ files for lighting scenes; empty = none allowed
};

class JobDefinition {
 public:
  virtual ~JobDefinition() = default;
  virtual std::string_view kind() const = 0;  // "integrate" | "lighting"
  virtual std::shared_ptr<const Kernel> kernel() const = 0;
  virtual StopRule stop_rule() const = 0;
  virtual uint64_t seed() const = 0;
  // What will run and why (estimator, domain, effects on/off), for status and validate.
  virtual nlohmann::json plan() const = 0;
  // Kind-specific result fields (per-point estimates, reference values, image info).
  virtual nlohmann::json result(const JobRunner& runner) const = 0;
  // `mean ± stderr (95% CI [lo, hi])` and what it is of, for the CLI.
  virtual std::string summary_line(const JobRunner& runner) const;
  // Non-null when the job produces an image (tiles, EXR/PNG); lives as long as the job.
  virtual const ImageSource* image() const { return nullptr; }
};

}  // namespace tally
