#pragma once
// Binary encodings of what crosses Redis: a Block (a work stream entry) and a
// BlockResult (a result hash field). Doubles travel as raw bits, so a result merged
// from Redis is bit-identical to one computed in process. Decoding checks lengths and
// a version byte and throws WireError, never reads past the input.
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include "common/engine/kernel.hpp"

namespace tally::cluster {

class WireError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

std::string encode_block(const Block& b);
Block decode_block(std::string_view bytes);
// k blocks back to back (a stream entry); throws WireError unless a whole number of blocks.
std::vector<Block> decode_blocks(std::string_view bytes);

std::string encode_result(const BlockResult& r);
BlockResult decode_result(std::string_view bytes);

// A stream entry's results, stored as one Redis hash field: each block's encoded result
// (encode_result) behind its length as 4 little-endian bytes, in block order.
void append_entry_result(std::string& entry, std::string_view encoded_result);
// Throws WireError unless `bytes` is one or more whole results.
std::vector<BlockResult> decode_entry_results(std::string_view bytes);

// Lower-case hex SHA-1 of an entry's encoded results (what redis.sha1hex would return):
// a worker sends it beside them, so Redis keeps digests without hashing every result.
std::string result_digest(std::string_view encoded);

}  // namespace tally::cluster
