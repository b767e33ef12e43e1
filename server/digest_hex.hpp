#pragma once
// A one-shot OpenSSL digest of some bytes as lower-case hex: the worker's result digests
// (SHA-1, server/cluster/wire.cpp) and token hashes (SHA-256, server/auth/token.cpp).
#include <openssl/evp.h>

#include <stdexcept>
#include <string>
#include <string_view>

namespace tally {

// Bytes as lower-case hex (a digest or MAC OpenSSL wrote).
inline std::string lower_hex(const unsigned char* md, size_t len) {
  static constexpr char kHex[] = "0123456789abcdef";
  std::string out(2 * len, '0');
  for (size_t i = 0; i < len; ++i) {
    out[2 * i] = kHex[md[i] >> 4];
    out[2 * i + 1] = kHex[md[i] & 15];
  }
  return out;
}

// Throws std::runtime_error(`failure`) if OpenSSL fails.
inline std::string digest_hex(const EVP_MD* type, std::string_view bytes, const char* failure) {
  unsigned char md[EVP_MAX_MD_SIZE];
  unsigned int len = 0;
  if (EVP_Digest(bytes.data(), bytes.size(), md, &len, type, nullptr) != 1) throw std::runtime_error(failure);
  return lower_hex(md, len);
}

}  // namespace tally
