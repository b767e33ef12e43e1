// libFuzzer: the checkpoint decoder. Any bytes decode or throw CheckpointError; a
// decoded state re-encodes to bytes that decode to the same encoding (round trip).
// An input that starts with the checkpoint magic has its last 8 bytes replaced by the
// checksum of the rest, so mutations of the seed corpus (whole checkpoints) reach the
// parser behind a valid checksum; other inputs go in as given (the checksum's path).
// Decoded sealed inputs of the current version (kCheckpointVersion) must re-encode to
// exactly their own bytes (older versions re-encode as the current one, which adds what
// they lacked or changes how it is stored).
#include <cstring>
#include <string>
#include <string_view>

#include "common/engine/checkpoint.hpp"
#include "fuzz_support.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  std::string bytes(reinterpret_cast<const char*>(data), size);
  const bool seal = size >= 16 && std::memcmp(data, "TALLYCK1", 8) == 0;
  if (seal) {
    bytes.resize(size - 8);
    const uint64_t h = tally::checkpoint_checksum(bytes);
    for (int i = 0; i < 8; ++i) bytes.push_back(static_cast<char>((h >> (8 * i)) & 0xff));
  }
  tally::JobState s;
  try {
    s = tally::decode_checkpoint(bytes);
  } catch (const tally::CheckpointError&) {
    return 0;
  }
  const std::string again = tally::encode_checkpoint(s);
  const bool current_version = bytes.size() >= 16 && static_cast<unsigned char>(bytes[8]) == tally::kCheckpointVersion &&
                               bytes.compare(9, 7, std::string(7, '\0')) == 0;
  if (seal && current_version && again != bytes) tally::fuzz::fail("a decoded checkpoint does not encode to its own bytes", "", bytes);
  try {
    if (tally::encode_checkpoint(tally::decode_checkpoint(again)) != again) {
      tally::fuzz::fail("round trip changed the state", "", bytes);
    }
  } catch (const tally::CheckpointError& e) {
    tally::fuzz::fail("re-encoded checkpoint does not decode", e.what(), bytes);
  }
  return 0;
}
