#pragma once
// What an integration job plans to run and what it found, as typed structs: the job
// itself (integration_job.hpp) fills them; common/protocol/integration_json.cpp writes
// them as JSON (docs/jobs.md). Optional fields not set are absent from the JSON.
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "common/engine/stop_rule.hpp"
#include "common/integrate/domain.hpp"
#include "common/integrate/integrand.hpp"

namespace tally {

struct DensityPlan {
  std::string type;               // "power" | "tabulated" | "cosine"
  std::vector<double> exponent;   // power: per dimension
  std::optional<uint64_t> cells;  // tabulated
};

// One estimator the automatic choice tried in its pilot (auto_estimator.hpp).
struct AutoCandidate {
  std::string estimator;     // "uniform" | "qmc" | "lattice"
  std::string periodize;     // lattice: "baker" | "none"; empty otherwise
  // Points per sample at each pilot size, ascending (uniform: {1}), and the sd of one
  // sample at each (non-finite: the pilot failed).
  std::vector<uint64_t> pilot_points;
  std::vector<double> pilot_sd;
  double rate = 0.5;          // fitted from the two largest sizes: the sd falls as evaluations^-rate
  uint64_t points = 1;        // points per sample it would run with
  // A vector integrand: the component that needs the most randomizations at `points`
  // (its pilot_sd and rate are the ones shown); 0 for a scalar one.
  size_t limiting_component = 0;
  double predicted_evaluations = 0.0;  // to the target (infinite: unusable)
};

// What `"estimator": {"type": "auto"}` chose and why.
struct AutoSelection {
  std::vector<AutoCandidate> candidates;
  size_t chosen = 0;
  size_t components = 1;  // of the integrand the pilot ran
  uint64_t pilot_evaluations = 0;  // points evaluated (each point evaluates every component)
  double target_half_width = 0.0;  // the absolute half-width the prediction aimed at (the limiting component's)
  std::string reason;              // one sentence, for people
};

// The estimator and its settings (the fields each estimator type sets, docs/jobs.md).
struct EstimatorPlan {
  std::optional<AutoSelection> selection;  // set when the spec asked for "auto"
  std::string type;
  std::optional<uint64_t> components;  // vector integrands
  std::optional<DensityPlan> density;  // importance
  std::optional<uint64_t> strata_per_dim, stratified_dims;  // stratified
  std::optional<uint64_t> points_per_sample;                // stratified, qmc
  std::optional<std::string> sequence, scramble;            // qmc ...
  std::optional<uint64_t> interlacing;                      // ... qmc (higher-order nets)
  std::optional<std::string> construction, periodize;       // lattice ...
  std::vector<uint64_t> generating_vector;
  std::vector<double> weights;
  std::optional<double> worst_case_error;                   // ... lattice
  std::optional<uint64_t> bins;                             // vegas ...
  std::optional<double> alpha;
  std::optional<uint64_t> warmup_passes, max_pass_samples;
  std::optional<std::string> combine, combination, steering;  // ... vegas
  std::optional<bool> stratify;                               // vegas+ ...
  std::optional<double> beta;
  std::optional<uint64_t> strata_per_axis;
  std::optional<std::string> stratification;                  // ... vegas+
  std::optional<uint64_t> max_attempts;                       // rejection
  std::optional<std::string> rule;                            // quadrature, cubature ...
  std::optional<uint64_t> max_evaluations;                    // cubature
  std::optional<std::string> error;                           // cubature: what its error is
  std::optional<uint64_t> points_per_dim;
  std::optional<double> points;  // ... (a product, may exceed 2^64 before the limit check)
};

struct IntegrationPlan {
  IntegrandInfo integrand;
  DomainInfo domain;
  EstimatorPlan estimator;
  uint64_t dimensions = 0;
  double measure = 0.0;
  StopRule stop;
  uint64_t seed = 0;
};

struct ComponentEstimate {
  double mean = 0.0;
  double std_error = 0.0;  // non-finite: unknown
  double ci_lo = 0.0, ci_hi = 0.0;
  // Deterministic rules (cubature): the rule's error estimate instead of std_error/ci.
  std::optional<double> error_estimate;
};

// How a vector integrand's components stand against the job's error target: the whole
// vector is summarised so that progress of thousands of components reads in one line.
struct ComponentsSummary {
  uint64_t count = 0;
  // Components whose interval half-width (or, for rules, error estimate) meets their
  // target: their own (stop.component_targets) or the stop rule's abs_error or rel_error;
  // absent when the job has no error target.
  std::optional<uint64_t> met;
  // The first kMaxUnmetListed components (by index) that do not meet their target; the
  // count of all of them is count - met.
  static constexpr size_t kMaxUnmetListed = 100;
  std::vector<uint64_t> unmet;
  // The component furthest from its target (half-width / target, the smaller over the two
  // targets), or with the largest relative half-width when there is no target.
  uint64_t worst = 0;
  double worst_half_width = 0.0;
  double worst_rel_half_width = 0.0;
};

struct VegasIterationSummary {
  uint64_t n = 0;
  double mean = 0.0;
  std::optional<double> std_error;  // needs n > 1
  bool warmup = false;
};

struct VegasSummary {
  std::vector<VegasIterationSummary> iterations;
  uint64_t used_iterations = 0;
  double chi2_per_dof = 0.0;  // non-finite: unknown
  double p_value = 1.0;
  bool consistent = true;
  double error_scale = 1.0;
  // VEGAS+: strata per axis, hypercubes, min/max samples per hypercube in the next round.
  std::optional<uint64_t> strata_per_axis, hypercubes, next_allocation_min, next_allocation_max;
};

struct IntegrationResult {
  IntegrandInfo integrand;
  DomainInfo domain;
  EstimatorPlan estimator;
  uint64_t evaluations = 0;
  std::string sample_unit;  // "point" | "point set" | "rule"
  // Deterministic rules only: the rule's own error estimate (non-finite: unknown).
  std::optional<double> error_estimate;
  // Vector integrands: each component's estimate and the covariance of the means.
  std::vector<ComponentEstimate> components;
  std::vector<std::vector<double>> covariance_of_means;  // only when the job keeps it
  std::optional<ComponentsSummary> components_summary;
  std::optional<VegasSummary> vegas;
  // Built-ins on their natural domains: the closed form and how far the estimate is.
  std::optional<double> reference;
  double error_vs_reference = 0.0;
  std::optional<double> z_score;
};

}  // namespace tally
