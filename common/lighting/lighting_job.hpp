#pragma once
// `kind: lighting` jobs: the JobDefinition that runs point queries or an image, with
// its plan and result as typed structs (lighting_plan.hpp). The spec reader that
// builds one is lighting_spec.hpp; the JSON views are common/protocol/lighting_json.hpp.
#include <memory>

#include "common/engine/job_definition.hpp"
#include "common/lighting/image_kernel.hpp"
#include "common/lighting/lighting_plan.hpp"
#include "common/lighting/point_kernel.hpp"

namespace tally {

class LightingJob final : public JobDefinition {
 public:
  // Exactly one of `points` and `image` is set.
  LightingJob(std::shared_ptr<const PointKernel> points, std::shared_ptr<const ImageKernel> image, StopRule stop,
              uint64_t seed, LightingPlan plan);

  std::string_view kind() const override { return "lighting"; }
  std::shared_ptr<const Kernel> kernel() const override { return kernel_; }
  StopRule stop_rule() const override { return stop_; }
  uint64_t seed() const override { return seed_; }
  const ImageSource* image() const override { return image_.get(); }
  std::string summary_line(const JobRunner& runner) const override;

  // What will run and why (effects on/off, sampler, scene), for status and validate.
  const LightingPlan& plan() const { return plan_; }
  // Per-point estimates of every estimator, or the image's size and error.
  LightingResult result(const JobRunner& runner) const;

 private:
  std::shared_ptr<const Kernel> kernel_;
  std::shared_ptr<const PointKernel> points_;
  std::shared_ptr<const ImageKernel> image_;
  StopRule stop_;
  uint64_t seed_ = 0;
  LightingPlan plan_;
};

}  // namespace tally
