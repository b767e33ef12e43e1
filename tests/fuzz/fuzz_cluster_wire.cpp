// libFuzzer: the cluster wire format (server/cluster/wire.hpp), what a coordinator reads
// back from Redis: a stream entry's blocks and an entry's results. A buggy or hostile
// worker, or a damaged Redis, may have written any bytes there. Any bytes decode or
// throw WireError (anything else, or a sanitizer report, is a finding). A decoded entry
// re-encodes to the same bytes (blocks have one encoding); decoded results re-encode to
// bytes that decode to the same encoding (the compact tallies have several encodings of
// one value, e.g. a +0.0 written out or left out).
#include <string>
#include <string_view>
#include <vector>

#include "fuzz_support.hpp"
#include "server/cluster/wire.hpp"

namespace {

std::string encode_entry(const std::vector<tally::BlockResult>& results) {
  std::string out;
  for (const tally::BlockResult& r : results) tally::cluster::append_entry_result(out, tally::cluster::encode_result(r));
  return out;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string_view bytes(reinterpret_cast<const char*>(data), size);
  const std::string input(bytes);
  try {
    const std::vector<tally::Block> blocks = tally::cluster::decode_blocks(bytes);
    std::string again;
    for (const tally::Block& b : blocks) again += tally::cluster::encode_block(b);
    if (again != bytes) tally::fuzz::fail("blocks re-encode differently", "", input);
  } catch (const tally::cluster::WireError&) {
  }
  std::vector<tally::BlockResult> results;
  try {
    results = tally::cluster::decode_entry_results(bytes);
  } catch (const tally::cluster::WireError&) {
    return 0;
  }
  const std::string again = encode_entry(results);
  try {
    const std::vector<tally::BlockResult> back = tally::cluster::decode_entry_results(again);
    if (back.size() != results.size()) tally::fuzz::fail("re-encoded results decode to another count", "", input);
    if (encode_entry(back) != again) tally::fuzz::fail("results round trip changed them", "", input);
  } catch (const tally::cluster::WireError& e) {
    tally::fuzz::fail("re-encoded results do not decode", e.what(), input);
  }
  return 0;
}
