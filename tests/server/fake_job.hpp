#pragma once
// A tiny job kind for the server's unit tests: deterministic values from a hash
// of (seed, sample index), a tunable cost per sample, and an optional tiled image.
//   {"kind": "fake", "seed": 1, "work": 0, "image": false, "stop": {...}}
#include <memory>
#include <nlohmann/json.hpp>

#include "common/engine/job_definition.hpp"

namespace tally::test {

std::unique_ptr<JobDefinition> compile_fake_job(const nlohmann::json& spec, const JobLimits& limits);

// More samples than any test waits for (the default per-job sample cap).
inline constexpr uint64_t kForever = 100'000'000'000ULL;

nlohmann::json fake_spec(uint64_t max_samples, uint64_t work = 0, uint64_t seed = 1, bool image = false);

}  // namespace tally::test
