#pragma once
// FNV-1a, 64 bits (offset basis 14695981039346656037, prime 1099511628211): the
// checkpoint trailer (common/engine/checkpoint.cpp) and the preview files' version
// tags (server/api/static_files.cpp). Not a cryptographic hash: for content digests
// that must resist collisions use common/hash/digest.hpp.
#include <cstdint>
#include <string_view>

namespace tally {

constexpr uint64_t fnv1a64(std::string_view bytes) noexcept {
  uint64_t h = 0xcbf29ce484222325ULL;
  for (const char c : bytes) {
    h ^= static_cast<unsigned char>(c);
    h *= 0x100000001b3ULL;
  }
  return h;
}

}  // namespace tally
