#pragma once
// What a validated job spec compiles to. The server, the CLI and the study only talk
// to jobs through this interface and JobRunner; each job kind (integrate, lighting)
// implements it in its own area, with its plan and result as typed structs of its own
// (IntegrationJob::plan(), LightingJob::result() ...) that common/protocol turns into JSON.
#include <cstdint>
#include <memory>
#include <string>
#include <string_view>

#include "common/engine/image_source.hpp"
#include "common/engine/job_runner.hpp"
#include "common/engine/kernel.hpp"
#include "common/engine/limits.hpp"
#include "common/engine/stop_rule.hpp"

namespace tally {

class JobDefinition {
 public:
  virtual ~JobDefinition() = default;
  virtual std::string_view kind() const = 0;  // "integrate" | "lighting"
  virtual std::shared_ptr<const Kernel> kernel() const = 0;
  virtual StopRule stop_rule() const = 0;
  virtual uint64_t seed() const = 0;
  // `mean ± stderr (95% CI [lo, hi])` and what it is of, for the CLI.
  virtual std::string summary_line(const JobRunner& runner) const;
  // Non-null when the job produces an image (tiles, EXR/PNG); lives as long as the job.
  virtual const ImageSource* image() const { return nullptr; }
};

}  // namespace tally
