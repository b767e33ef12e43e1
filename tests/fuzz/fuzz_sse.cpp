// libFuzzer: the event-stream parsers and Last-Event-ID. Oracle: feeding the bytes
// whole or cut into arbitrary pieces gives the same events (the socket may split
// anywhere); the server's Last-Event-ID parser accepts exactly the decimal uint64s.
#include <charconv>
#include <string>
#include <vector>

#include "client/sse_parser.hpp"
#include "fuzz_support.hpp"
#include "server/api/job_event_stream.hpp"

namespace {

std::string run(std::string_view text, const std::vector<size_t>& cuts) {
  std::string out;
  tally::SseParser p([&](const tally::SseEvent& e) { out += e.id + '\x1f' + e.event + '\x1f' + e.data + '\x1e'; });
  size_t at = 0;
  for (size_t c : cuts) {
    if (c > at && c <= text.size()) {
      p.feed(text.substr(at, c - at));
      at = c;
    }
  }
  p.feed(text.substr(at));
  return out + "|" + p.last_event_id();
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size < 1) return 0;
  const std::string text(reinterpret_cast<const char*>(data) + 1, size - 1);
  std::vector<size_t> cuts;
  for (size_t c = 1 + data[0] % 7; c < text.size(); c += 1 + (c * 31 + data[0]) % 11) cuts.push_back(c);
  const std::string whole = run(text, {});
  const std::string pieces = run(text, cuts);
  if (whole != pieces) tally::fuzz::fail("SSE events depend on how the bytes were split", "", text);

  const auto id = tally::parse_last_event_id(text);
  if (id) {
    // Accepted: the text is spaces around a decimal number that reads back as id.
    size_t b = text.find_first_not_of(' '), e = text.find_last_not_of(' ');
    const std::string digits = text.substr(b, e - b + 1);
    if (digits.find_first_not_of("0123456789") != std::string::npos || std::to_string(*id).size() > digits.size()) {
      tally::fuzz::fail("Last-Event-ID accepted a non-number", std::to_string(*id), text);
    }
  }
  // NDJSON: throws on bad lines, never crashes.
  try {
    tally::NdjsonParser nd([](const tally::SseEvent&) {});
    nd.feed(text);
  } catch (const std::exception&) {
    return 0;
  }
  return 0;
}
