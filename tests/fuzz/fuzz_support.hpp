#pragma once
// Shared by the libFuzzer targets: a finding prints what differed and aborts, so
// libFuzzer saves the input (then: make it a unit test, see tests/fuzz/README.md).
#include <cstdio>
#include <cstdlib>
#include <string>

namespace tally::fuzz {

[[noreturn]] inline void fail(const char* what, const std::string& detail, const std::string& input) {
  std::fprintf(stderr, "FUZZ FINDING: %s: %s\ninput (%zu bytes): %.400s\n", what, detail.c_str(), input.size(),
               input.c_str());
  std::abort();
}

}  // namespace tally::fuzz
