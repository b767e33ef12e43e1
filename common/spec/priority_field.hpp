#pragma once
// A job's priority (docs/api.md "Scheduling"): -5..5, weight priority + 6. Set at submit
// (POST /v1/jobs?priority=N) and changed later with PATCH /v1/jobs/{id}, whose body this
// reads: {"priority": N}, nothing else.
#include <nlohmann/json.hpp>

namespace tally {

inline constexpr int kMinPriority = -5;
inline constexpr int kMaxPriority = 5;

// The body of a priority change: an object with exactly the integer "priority" in
// [-5, 5]. SpecError naming /priority (a bad value), the unknown field, or "" (not an
// object, or no field at all).
int read_priority_change(const nlohmann::json& body);

}  // namespace tally
