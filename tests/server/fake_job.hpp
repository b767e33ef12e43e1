#pragma once
// A tiny job kind for the server's unit tests: deterministic values from a hash
// of (seed, sample index), a tunable cost per sample, and an optional tiled image.
//   {"kind": "fake", "seed": 1, "work": 0, "image": false, "fold_gate": false, "stop": {...}}
#include <condition_variable>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>

#include "common/engine/job_definition.hpp"

namespace tally::test {

std::unique_ptr<JobDefinition> compile_fake_job(const nlohmann::json& spec, const JobLimits& limits);

// More samples than any test waits for (the default per-job sample cap).
inline constexpr uint64_t kForever = 100'000'000'000ULL;

nlohmann::json fake_spec(uint64_t max_samples, uint64_t work = 0, uint64_t seed = 1, bool image = false);

// With "fold_gate": true the fake kernel folds its passes (Kernel::folds_passes), and
// its fold_pass — inside the runner's merge of a pass — waits at this gate while it is
// armed: a test holds a pass's merge open to see what does not wait for it. Waits are
// bounded (60 s) so that a failing test cannot hang.
class FoldGate {
 public:
  void arm();                               // the next fold_pass waits until release()
  bool wait_entered(double seconds);        // a fold_pass is waiting at the gate
  void release();                           // it goes on, and so do later ones
  void pass();                              // called by fold_pass

 private:
  std::mutex mu_;
  std::condition_variable cv_;
  bool armed_ = false, entered_ = false;
};
FoldGate& fold_gate();

}  // namespace tally::test
