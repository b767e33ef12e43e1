#pragma once
// `kind: integrate` jobs: the JobDefinition that runs them, with its plan and result
// as typed structs (integration_plan.hpp). The spec reader that builds one is
// integration_spec.hpp; the JSON views are common/protocol/integration_json.hpp.
#include <memory>
#include <optional>
#include <string>

#include "common/engine/job_definition.hpp"
#include "common/integrate/integration_plan.hpp"

namespace tally {

class IntegrationJob final : public JobDefinition {
 public:
  struct Setup {
    std::shared_ptr<const Kernel> kernel;
    std::shared_ptr<const Integrand> integrand;
    std::shared_ptr<const Domain> domain;
    EstimatorPlan estimator;
    StopRule stop;
    uint64_t seed = 1;
    bool sweep = false;          // one sample = one point set
    bool deterministic = false;  // a quadrature rule: one sample, no randomness
    std::optional<double> reference;  // the closed form, when known
  };
  explicit IntegrationJob(Setup s);


  std::string_view kind() const override { return "integrate"; }
  std::shared_ptr<const Kernel> kernel() const override { return s_.kernel; }
  StopRule stop_rule() const override { return s_.stop; }
  uint64_t seed() const override { return s_.seed; }
  std::string summary_line(const JobRunner& runner) const override;

  // What will run and why, for status and validate.
  const IntegrationPlan& plan() const { return plan_; }
  // Per-component estimates, VEGAS iterations, reference values.
  IntegrationResult result(const JobRunner& runner) const;

 private:
  Setup s_;
  IntegrationPlan plan_;
};

// Count, met (against the stop rule's error target) and worst of a vector's components.
ComponentsSummary summarize_components(const std::vector<ComponentEstimate>& comps, const StopRule& stop);

}  // namespace tally
