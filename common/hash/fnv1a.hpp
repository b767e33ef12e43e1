#pragma once
// FNV-1a, 64 bits (offset basis 14695981039346656037, prime 1099511628211): the
// checkpoint trailer (common/engine/checkpoint.cpp) and the preview files' version
// tags (server/api/static_files.cpp). Not a cryptographic hash: for content digests
// that must resist collisions use common/hash/digest.hpp.
#include <cstdint>
#include <string_view>

namespace tally {

constexpr uint64_t kFnv1a64Basis = 0xcbf29ce484222325ULL;

// The hash of `h`'s bytes followed by `bytes`: a hash taken piece by piece (a checkpoint
// streamed to the store) is fnv1a64_update over the pieces in order, from kFnv1a64Basis.
constexpr uint64_t fnv1a64_update(uint64_t h, std::string_view bytes) noexcept {
  for (const char c : bytes) {
    h ^= static_cast<unsigned char>(c);
    h *= 0x100000001b3ULL;
  }
  return h;
}

constexpr uint64_t fnv1a64(std::string_view bytes) noexcept { return fnv1a64_update(kFnv1a64Basis, bytes); }

}  // namespace tally
