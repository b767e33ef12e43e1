#pragma once
// Cryptographic digests as lower-case hex, on OpenSSL's EVP interface, every return
// value checked: SHA-256 (asset names, token hashes) and SHA-1 (the cluster's result
// digests). Failures throw DigestError.
#include <cstddef>
#include <memory>
#include <stdexcept>
#include <string>
#include <string_view>

namespace tally {

class DigestError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// Lower-case hex of `n` bytes.
std::string hex_encode(const unsigned char* bytes, size_t n);

std::string sha256_hex(std::string_view bytes);
std::string sha1_hex(std::string_view bytes);

// SHA-256 of a body that arrives in parts (uploads, files read in blocks).
class Sha256 {
 public:
  Sha256();
  ~Sha256();
  Sha256(const Sha256&) = delete;
  Sha256& operator=(const Sha256&) = delete;
  void update(std::string_view part);
  // The digest of everything updated so far; the object is spent afterwards.
  std::string finish_hex();

 private:
  struct Ctx;
  std::unique_ptr<Ctx> ctx_;
};

}  // namespace tally
