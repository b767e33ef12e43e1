#include "common/hash/digest.hpp"

#include <openssl/evp.h>

namespace tally {

namespace {

std::string one_shot(const EVP_MD* type, std::string_view bytes, const char* name) {
  unsigned char md[EVP_MAX_MD_SIZE];
  unsigned int len = 0;
  if (EVP_Digest(bytes.data(), bytes.size(), md, &len, type, nullptr) != 1) {
    throw DigestError(std::string(name) + " failed (OpenSSL)");
  }
  return hex_encode(md, len);
}

}  // namespace

std::string hex_encode(const unsigned char* bytes, size_t n) {
  static constexpr char kHex[] = "0123456789abcdef";
  std::string out(2 * n, '0');
  for (size_t i = 0; i < n; ++i) {
    out[2 * i] = kHex[bytes[i] >> 4];
    out[2 * i + 1] = kHex[bytes[i] & 15];
  }
  return out;
}

std::string sha256_hex(std::string_view bytes) { return one_shot(EVP_sha256(), bytes, "SHA-256"); }

std::string sha1_hex(std::string_view bytes) { return one_shot(EVP_sha1(), bytes, "SHA-1"); }

struct Sha256::Ctx {
  EVP_MD_CTX* md = EVP_MD_CTX_new();
  ~Ctx() { EVP_MD_CTX_free(md); }
};

Sha256::Sha256() : ctx_(std::make_unique<Ctx>()) {
  if (!ctx_->md || EVP_DigestInit_ex(ctx_->md, EVP_sha256(), nullptr) != 1) {
    throw DigestError("cannot initialise SHA-256 (OpenSSL)");
  }
}

Sha256::~Sha256() = default;

void Sha256::update(std::string_view part) {
  if (EVP_DigestUpdate(ctx_->md, part.data(), part.size()) != 1) throw DigestError("SHA-256 update failed (OpenSSL)");
}

std::string Sha256::finish_hex() {
  unsigned char md[EVP_MAX_MD_SIZE];
  unsigned int len = 0;
  if (EVP_DigestFinal_ex(ctx_->md, md, &len) != 1) throw DigestError("SHA-256 final failed (OpenSSL)");
  return hex_encode(md, len);
}

}  // namespace tally
