#pragma once
// Sizes for the memory and retention flags: the default memory budget (from the
// machine or its cgroup limit) and the parsers of "4GiB" and "7d".
#include <cstdint>
#include <optional>
#include <string_view>

namespace tally {

// Half of the memory this process may use: the smaller of the machine's MemTotal and
// the cgroup limit (server/host/host_facts.hpp); 0 if neither is known.
uint64_t default_memory_budget();

// "4GiB", "512MiB", "64KiB", "2GB" (powers of 1000), "1000000" (bytes); nullopt if not a size.
std::optional<uint64_t> parse_byte_size(std::string_view s);
// "90" or "90s", "15m", "12h", "7d"; nullopt if not a duration.
std::optional<double> parse_duration_s(std::string_view s);

}  // namespace tally
