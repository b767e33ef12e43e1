#pragma once
// A job's worker pool (the spec's top-level "pool", docs/api.md): in cluster mode only
// tally-worker processes started with --pool NAME compute it; "" (absent) = any worker.
// In process every pool is the server's own threads: the field is checked and then
// changes nothing. One rule for names, used by the spec readers, tally-worker --pool
// and the auth file's per-principal "pools".
#include <nlohmann/json.hpp>
#include <string>
#include <string_view>

#include "common/spec/spec_reader.hpp"

namespace tally {

inline constexpr size_t kMaxPoolName = 64;
// 1-64 characters of [A-Za-z0-9._-].
bool valid_pool_name(std::string_view name);
// What is wrong with `name` as a pool name, for an error message ("" when valid).
std::string pool_name_problem(std::string_view name);
// The spec's "pool" ("" when absent); throws SpecError at /pool for a bad value.
std::string read_pool(SpecReader& root);
// The pool of a spec the readers accepted ("" = any).
std::string spec_pool(const nlohmann::json& spec);

}  // namespace tally
