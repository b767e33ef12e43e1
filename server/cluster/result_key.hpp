#pragma once
// The cluster's shared secret (--result-key-file on tally-server and every tally-worker)
// and what it signs: each entry's results (the digest the store script keeps and the
// coordinator checks before merging) and each job's spec and asset manifest (checked by
// a worker before it compiles them). With a key, whoever can write to Redis but does
// not hold the key can neither change a result nor run a spec of their own without the
// job failing loudly; without one, the digests are plain SHA-1 (they catch corruption,
// not an attacker). docs/security.md, "Cluster mode".
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>

namespace tally::cluster {

// Reads the key file: its bytes, a trailing newline dropped. Throws std::runtime_error
// naming the file when it cannot be read or holds fewer than 32 bytes.
std::string load_result_key(const std::string& path);

// The digest of an entry's results: HMAC-SHA-256 under `key` of the job, run, pass and
// first slot and the results (so a result cannot be moved to another entry either),
// lower-case hex; without a key, result_digest(results) (SHA-1, wire.hpp).
std::string entry_digest(std::string_view key, std::string_view job, std::string_view run, uint64_t pass,
                         std::string_view slot, std::string_view results);

// What is wrong with the results of the entry at `slot` given the digest the store kept
// with them (nullopt: none): an error that fails the job, or "" when they match.
std::string check_entry_digest(std::string_view key, std::string_view job, std::string_view run, uint64_t pass,
                               std::string_view slot, std::string_view results, const std::optional<std::string>& digest);

// HMAC-SHA-256 under `key` of the job's id, run, spec and asset manifest, lower-case hex.
std::string spec_mac(std::string_view key, std::string_view job, std::string_view run, std::string_view spec,
                     std::string_view manifest);

// Equal strings, in time independent of where they differ.
bool same_digest(std::string_view a, std::string_view b);

}  // namespace tally::cluster
