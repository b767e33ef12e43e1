#pragma once
// Shared pieces of the study's sections: running a spec or a kernel through the
// production path, a tiny CSV writer, the Genz spec builder and the command options.
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "common/engine/job_definition.hpp"
#include "common/engine/job_runner.hpp"
#include "common/engine/kernel.hpp"
#include "bench/peers/genz_scalar.hpp"
#include "common/integrate/genz.hpp"

namespace tally::study {

using nlohmann::json;

struct Options {
  std::filesystem::path out = "docs/study";
  bool quick = false;  // a smoke run: fewer seeds and sizes (not for the report)
  unsigned threads = 1;
};

// One finished job. `seconds`: wall time of compile + run (what a user waits for);
// `compute_seconds`: the runner's pass time (what the engine's rates are based on).
struct JobRun {
  std::unique_ptr<JobDefinition> job;  // null for a bare kernel
  std::unique_ptr<JobRunner> runner;
  double seconds = 0.0;
  double compute_seconds() const { return runner->state().compute_seconds; }
  // The kernel's "evaluations" counter (every kernel the study runs declares one).
  uint64_t evaluations() const {
    const JobState& s = runner->state();
    for (size_t i = 0; i < s.counter_names.size(); ++i) {
      if (s.counter_names[i] == "evaluations") return s.counters[i];
    }
    return 0;
  }
};

JobRun run_spec(const json& spec, unsigned threads = 1);
JobRun run_kernel(std::shared_ptr<const Kernel> kernel, const StopRule& rule, unsigned threads = 1);

// Independent repetitions of one job (seeds 1..R): the estimator's spread and error.
struct SeedStats {
  int seeds = 0;
  double mean = 0.0;             // of the estimates
  double rmse = 0.0;             // sqrt(mean((estimate - exact)^2))
  double variance = 0.0;         // of the estimates across seeds (unbiased)
  double reported_var = 0.0;     // mean of the engine's std_error^2
  double seconds = 0.0;          // mean runner compute seconds
  double evaluations = 0.0;      // mean evaluations
};
SeedStats over_seeds(const std::function<json(uint64_t seed)>& spec_of, double exact, int seeds,
                     unsigned threads = 1);

// The same Genz instance as the peers' scalar integrand (p must outlive it).
peers::GenzScalar peer_integrand(const GenzParams& p);

// One Genz instance as bench/peers/scipy_peer.py reads it (instances.json,
// hard_instances.json): family name and index, d, instance number, a, u, the exact value.
json scipy_instance(const GenzParams& p, int instance, double exact);

// An integrate job over [0,1]^d with a Genz built-in.
json genz_spec(const GenzParams& p, const json& estimator, const json& stop, uint64_t seed);

class Csv {
 public:
  Csv(const std::filesystem::path& path, const std::vector<std::string>& columns);
  ~Csv();
  Csv(const Csv&) = delete;
  Csv& operator=(const Csv&) = delete;
  // One row; numbers printed with 17 significant digits, strings as given.
  void row(const std::vector<json>& cells);

 private:
  std::FILE* f_ = nullptr;
  size_t columns_ = 0;
};

// Wall-clock seconds since construction.
class Stopwatch {
 public:
  double seconds() const {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0_).count();
  }

 private:
  std::chrono::steady_clock::time_point t0_ = std::chrono::steady_clock::now();
};

void log(const std::string& line);

// TALLY_STUDY_FAMILIES=name,name limits the peer studies to some families (all when unset);
// TALLY_STUDY_INSTANCES=N sets the instances per family and dimension.
bool family_selected(GenzFamily f);

// The sections; each writes its CSVs under options.out.
void run_quadrature_study(const Options& o);
void run_variance_study(const Options& o);
void run_disk_study(const Options& o);
void run_lighting_study(const Options& o);
void run_rqmc_study(const Options& o);
void run_peer_study(const Options& o);
void run_peer_tuning(const Options& o);
void run_vegas_tuning(const Options& o);
void run_eta_study(const Options& o);
void run_hard_study(const Options& o);

}  // namespace tally::study
