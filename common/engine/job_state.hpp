#pragma once
// Everything a running job has accumulated. It is exactly what a checkpoint stores:
// a job resumed from it continues bit-identically.
#include <cstdint>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include "common/engine/counters.hpp"
#include "common/engine/results_version.hpp"
#include "common/engine/sample_stats.hpp"
#include "common/stats/tail_index.hpp"
#include "common/stats/tally.hpp"

namespace tally {

struct TracePoint {
  double time_s = 0.0;  // compute time since the job started
  uint64_t samples = 0;
  double mean = 0.0;
  double std_error = 0.0;
  friend bool operator==(const TracePoint&, const TracePoint&) = default;
};

struct JobState {
  uint64_t passes = 0;
  uint64_t samples = 0;  // samples per channel the schedule has completed
  std::vector<uint64_t> partition_samples;
  std::vector<Tally> channels;
  // Sum channels (Kernel::sum_count): sums of samples whose counts the kernel derives
  // from partition_samples, kept in single precision (an image's replicates: 4 bytes a
  // channel). A result's sums are doubles, added in the sample order of its blocks; each
  // merge adds one in double and rounds the total once (JobRunner::merge_group), so a
  // sum carries one rounding of 2^-24 relative per merged result group, not per sample.
  std::vector<float> sums;
  Counters counters;  // indexed like counter_names
  // The kernel's counter names (Kernel::counter_names), kept with the values so that a
  // checkpoint says what it counted: a resumed job maps them by name.
  std::vector<std::string> counter_names;
  TailTracker tail{512};
  WeightStats weights;
  std::optional<SampleFault> fault;
  double compute_seconds = 0.0;
  std::vector<TracePoint> trace;  // thinned to at most kMaxTrace points
  // Bytes owned by the kernel (Kernel::fold_pass), e.g. the VEGAS grid and its
  // iterations: checkpointed with the rest, so an adaptive job resumes bit-identically.
  std::string kernel_state;
  // The engine generation that computed it (results_version.hpp); a state read from an
  // older checkpoint keeps the version it was written with (0: before it was recorded).
  uint32_t results_version = kResultsVersion;

  static constexpr size_t kMaxTrace = 512;
};

// Bytes a job's state takes in memory while it runs, the one estimate both the spec
// readers (against JobLimits::max_state_bytes) and the server's admission (against its
// memory budget) use: the runner's JobState (a Tally per channel, a float per sum
// channel, a sample count per partition) plus one more copy in flight (a pass's results,
// where a sum is a double, or a snapshot being written). Saturates at UINT64_MAX.
inline uint64_t job_state_bytes(uint64_t channels, uint64_t partitions, uint64_t sums = 0) {
  constexpr uint64_t kCopies = 2;
  constexpr uint64_t kSumBytes = sizeof(float) + sizeof(double);  // the state's, a result's
  constexpr uint64_t kMax = std::numeric_limits<uint64_t>::max();
  constexpr uint64_t kPart = kMax / 4;  // each term below this: their sum cannot wrap
  if (channels > kPart / (kCopies * sizeof(Tally)) || partitions > kPart / (kCopies * sizeof(uint64_t)) ||
      sums > kPart / kSumBytes) {
    return kMax;
  }
  return kCopies * (channels * sizeof(Tally) + partitions * sizeof(uint64_t)) + sums * kSumBytes;
}

}  // namespace tally
