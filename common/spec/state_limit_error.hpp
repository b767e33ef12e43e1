#pragma once
// The refusal a job's size earns: its state (job_state_bytes) over
// JobLimits::max_state_bytes. A SpecError naming the field that makes the state big, of
// its own type so that whoever tightened the limit (the server, to its memory budget)
// can say so without compiling the spec again.
#include "common/spec/spec_reader.hpp"

namespace tally {

class StateLimitError : public SpecError {
 public:
  using SpecError::SpecError;
};

}  // namespace tally
