#pragma once
// The per-job caps (JobLimits) as command-line flags, written once for tally-server and
// tally-worker: a worker re-validates every spec it reads with its own limits, so the
// two must offer the same flags (give workers at least the server's values).
// --max-state-bytes defaults to the machine's default memory budget (half its memory or
// cgroup limit, server/host/memory_budget.hpp), so a worker on the same kind of machine
// admits what the server admits.
#include <CLI/CLI.hpp>

#include <cstddef>
#include <string>

#include "common/engine/limits.hpp"
#include "server/host/memory_budget.hpp"

namespace tally {

inline void add_job_limit_flags(CLI::App& app, JobLimits& l) {
  app.add_option("--max-dimensions", l.max_dimensions, "per-job cap: integration dimensions")->capture_default_str();
  if (const uint64_t m = default_memory_budget()) l.max_state_bytes = m;
  app.add_option_function<std::string>(
         "--max-state-bytes",
         [&l](const std::string& v) {
           const auto b = parse_byte_size(v);
           if (!b || *b == 0) throw CLI::ValidationError("--max-state-bytes", v + " is not a size (4GiB, 512MiB, bytes)");
           l.max_state_bytes = *b;
         },
         "per-job cap: bytes of a job's state in memory (an image's pixels, a point query's points); default: half "
         "the machine's memory")
      ->default_str(std::to_string(l.max_state_bytes));
  app.add_option("--max-samples", l.max_samples, "per-job cap: samples")->capture_default_str();
  app.add_option("--max-seconds", l.max_seconds, "per-job cap: compute seconds")->capture_default_str();
  app.add_option("--max-pixels", l.max_pixels, "per-job cap: image pixels")->capture_default_str();
  app.add_option("--max-triangles", l.max_triangles, "per-job cap: triangles of a lighting scene (~100 bytes each)")
      ->check(CLI::Range(size_t{1}, size_t{1} << 31))
      ->capture_default_str();
  app.add_option("--max-texture-bytes", l.max_texture_bytes, "per-job cap: decoded texture bytes (12 a texel)")
      ->capture_default_str();
  // Scene files (docs/security.md, "Scene files"): checked before what they count is allocated.
  app.add_option("--max-vertices", l.max_vertices, "per-job cap: mesh vertices of a lighting scene")->capture_default_str();
  app.add_option("--max-shapes", l.max_shapes, "per-job cap: shapes (glTF primitives, OBJ material groups)")
      ->check(CLI::Range(size_t{1}, size_t{1} << 24))
      ->capture_default_str();
  app.add_option("--max-gltf-nodes", l.max_gltf_nodes, "per-job cap: entries of a glTF's nodes (and other top-level arrays)")
      ->capture_default_str();
  app.add_option("--max-file-json-depth", l.max_file_json_depth, "per-job cap: nesting depth of a glTF's JSON")
      ->check(CLI::Range(size_t{4}, size_t{1024}))
      ->capture_default_str();
  app.add_option("--max-polygon-vertices", l.max_polygon_vertices, "per-job cap: corners of one OBJ face")
      ->check(CLI::Range(size_t{3}, size_t{65536}))
      ->capture_default_str();
  app.add_option("--max-image-channels", l.max_image_channels, "per-job cap: channels of one image file")
      ->check(CLI::Range(size_t{1}, size_t{1024}))
      ->capture_default_str();
  app.add_option("--max-decode-bytes", l.max_decode_bytes, "per-job cap: bytes decoding a scene's images takes")
      ->capture_default_str();
}

}  // namespace tally
