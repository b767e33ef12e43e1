#include "server/cluster/result_key.hpp"

#include <fmt/format.h>
#include <openssl/crypto.h>
#include <openssl/core_names.h>
#include <openssl/evp.h>
#include <openssl/params.h>

#include <fstream>
#include <initializer_list>
#include <iterator>
#include <stdexcept>

#include "server/cluster/wire.hpp"
#include "common/hash/digest.hpp"

namespace tally::cluster {

namespace {

constexpr size_t kMinKeyBytes = 32;

// HMAC-SHA-256 under `key` of the parts, concatenated (streamed: a large result is not copied).
std::string hmac_hex(std::string_view key, std::initializer_list<std::string_view> parts) {
  EVP_MAC* mac = EVP_MAC_fetch(nullptr, "HMAC", nullptr);
  EVP_MAC_CTX* ctx = mac ? EVP_MAC_CTX_new(mac) : nullptr;
  char digest[] = "SHA256";
  const OSSL_PARAM params[] = {OSSL_PARAM_construct_utf8_string("digest", digest, 0), OSSL_PARAM_construct_end()};
  unsigned char out[EVP_MAX_MD_SIZE];
  size_t len = 0;
  bool ok = ctx && EVP_MAC_init(ctx, reinterpret_cast<const unsigned char*>(key.data()), key.size(), params) == 1;
  for (std::string_view p : parts) {
    ok = ok && EVP_MAC_update(ctx, reinterpret_cast<const unsigned char*>(p.data()), p.size()) == 1;
  }
  ok = ok && EVP_MAC_final(ctx, out, &len, sizeof out) == 1;
  EVP_MAC_CTX_free(ctx);
  EVP_MAC_free(mac);
  if (!ok) throw std::runtime_error("HMAC-SHA-256 failed (OpenSSL)");
  return hex_encode(out, len);
}

}  // namespace

std::string load_result_key(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error(fmt::format("cannot read the result key file {}", path));
  std::string key((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  while (!key.empty() && (key.back() == '\n' || key.back() == '\r')) key.pop_back();
  if (key.size() < kMinKeyBytes) {
    throw std::runtime_error(fmt::format("the result key file {} holds {} bytes; it needs at least {} (e.g. "
                                         "openssl rand -hex 32 > {})",
                                         path, key.size(), kMinKeyBytes, path));
  }
  return key;
}

std::string entry_digest(std::string_view key, std::string_view job, std::string_view run, uint64_t pass,
                         std::string_view slot, std::string_view results) {
  if (key.empty()) return result_digest(results);
  const std::string head = fmt::format("tally-entry\n{}\n{}\n{}\n{}\n", job, run, pass, slot);
  return hmac_hex(key, {head, results});
}

std::string check_entry_digest(std::string_view key, std::string_view job, std::string_view run, uint64_t pass,
                               std::string_view slot, std::string_view results, const std::optional<std::string>& digest) {
  if (digest && same_digest(*digest, entry_digest(key, job, run, pass, slot, results))) return {};
  return fmt::format("the results of the entry at block slot {} of pass {} do not match their {} digest: they were "
                     "changed in Redis (or a worker's --result-key-file differs from the server's); the job fails "
                     "rather than merge them",
                     slot, pass, key.empty() ? "SHA-1" : "keyed (HMAC-SHA-256)");
}

std::string spec_mac(std::string_view key, std::string_view job, std::string_view run, std::string_view spec,
                     std::string_view manifest) {
  const std::string head = fmt::format("tally-spec\n{}\n{}\n{}\n", job, run, spec.size());
  return hmac_hex(key, {head, spec, manifest});
}

bool same_digest(std::string_view a, std::string_view b) {
  return a.size() == b.size() && CRYPTO_memcmp(a.data(), b.data(), a.size()) == 0;
}

}  // namespace tally::cluster
