#pragma once
// Binary checkpoint of a JobState, taken at pass boundaries. Doubles are stored as
// raw bits, so a resumed job continues bit-identically. A checksum guards against
// truncation and corruption: decoding never silently returns a reset state.
#include <cstddef>
#include <cstdint>
#include <functional>
#include <stdexcept>
#include <string>
#include <string_view>

#include "common/engine/job_state.hpp"

namespace tally {

class CheckpointError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// Receives a checkpoint's bytes in order, one piece at a time (a store writes each as it
// comes: no buffer of the whole checkpoint, and no SQLite blob over its size limit).
using CheckpointSink = std::function<void(std::string_view piece)>;
inline constexpr size_t kCheckpointPieceBytes = size_t{16} << 20;
// The version encode_checkpoint writes (its history: checkpoint.cpp); decode reads 1 to it.
inline constexpr uint32_t kCheckpointVersion = 6;

// Streams the checkpoint of `state` to `sink` in pieces of exactly `piece_bytes` (the
// last one shorter), holding about one piece besides the state: the pieces joined are
// encode_checkpoint's bytes. Returns their total size.
uint64_t write_checkpoint(const JobState& state, const CheckpointSink& sink, size_t piece_bytes = kCheckpointPieceBytes);
std::string encode_checkpoint(const JobState& state);
// At least the size of `state`'s checkpoint (what encode_checkpoint reserves).
uint64_t checkpoint_size_hint(const JobState& state);
JobState decode_checkpoint(std::string_view bytes);  // throws CheckpointError
// The checksum that ends a checkpoint, of the bytes before it (magic included). Tests and
// the fuzz target damage a body and re-append it, so the parser's own checks run.
uint64_t checkpoint_checksum(std::string_view body);

}  // namespace tally
