// libFuzzer: the checkpoint decoder. Any bytes decode or throw CheckpointError; a
// decoded state re-encodes to bytes that decode to the same encoding (round trip).
#include <string>
#include <string_view>

#include "common/engine/checkpoint.hpp"
#include "fuzz_support.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string_view bytes(reinterpret_cast<const char*>(data), size);
  tally::JobState s;
  try {
    s = tally::decode_checkpoint(bytes);
  } catch (const tally::CheckpointError&) {
    return 0;
  }
  const std::string again = tally::encode_checkpoint(s);
  try {
    if (tally::encode_checkpoint(tally::decode_checkpoint(again)) != again) {
      tally::fuzz::fail("round trip changed the state", "", std::string(bytes));
    }
  } catch (const tally::CheckpointError& e) {
    tally::fuzz::fail("re-encoded checkpoint does not decode", e.what(), std::string(bytes));
  }
  return 0;
}
