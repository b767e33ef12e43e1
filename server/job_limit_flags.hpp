#pragma once
// The per-job caps (JobLimits) as command-line flags, written once for tally-server and
// tally-worker: a worker re-validates every spec it reads with its own limits, so the
// two must offer the same flags (give workers at least the server's values).
#include <CLI/CLI.hpp>

#include <cstddef>

#include "common/engine/limits.hpp"

namespace tally {

inline void add_job_limit_flags(CLI::App& app, JobLimits& l) {
  app.add_option("--max-dimensions", l.max_dimensions, "per-job cap: integration dimensions")->capture_default_str();
  app.add_option("--max-channels", l.max_channels, "per-job cap: channels")->capture_default_str();
  app.add_option("--max-samples", l.max_samples, "per-job cap: samples")->capture_default_str();
  app.add_option("--max-seconds", l.max_seconds, "per-job cap: compute seconds")->capture_default_str();
  app.add_option("--max-pixels", l.max_pixels, "per-job cap: image pixels")->capture_default_str();
  app.add_option("--max-triangles", l.max_triangles, "per-job cap: triangles of a lighting scene (~100 bytes each)")
      ->check(CLI::Range(size_t{1}, size_t{1} << 31))
      ->capture_default_str();
  app.add_option("--max-texture-bytes", l.max_texture_bytes, "per-job cap: decoded texture bytes (12 a texel)")
      ->capture_default_str();
}

}  // namespace tally
