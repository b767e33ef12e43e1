#pragma once
// Bearer tokens: random 256-bit secrets, stored only as their SHA-256 hash, compared
// in constant time. OpenSSL (libcrypto) provides the randomness and the hash.
#include <string>
#include <string_view>

namespace tally {

// A fresh token: "tly_" + 43 base64url characters (32 bytes from RAND_bytes).
std::string generate_token();
// A fresh opaque id of the same strength for browser sessions (no prefix).
std::string generate_session_id();
// Lower-case hex SHA-256 of the token's bytes (64 characters).
std::string token_sha256_hex(std::string_view token);
// Constant-time equality of two equal-length strings (CRYPTO_memcmp); false if the
// lengths differ (lengths are not secret: every stored hash has 64 characters).
bool constant_time_equal(std::string_view a, std::string_view b);
// RFC 6750 b64token syntax: 1*( ALPHA / DIGIT / "-" / "." / "_" / "~" / "+" / "/" ) *"=".
bool is_b64token(std::string_view s);

}  // namespace tally
