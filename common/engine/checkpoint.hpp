#pragma once
// Binary checkpoint of a JobState, taken at pass boundaries. Doubles are stored as
// raw bits, so a resumed job continues bit-identically. A checksum guards against
// truncation and corruption: decoding never silently returns a reset state.
#include <stdexcept>
#include <string>
#include <string_view>

#include "common/engine/job_state.hpp"

namespace tally {

class CheckpointError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

std::string encode_checkpoint(const JobState& state);
JobState decode_checkpoint(std::string_view bytes);  // throws CheckpointError
// The checksum that ends a checkpoint, of the bytes before it (magic included). Tests and
// the fuzz target damage a body and re-append it, so the parser's own checks run.
uint64_t checkpoint_checksum(std::string_view body);

}  // namespace tally
