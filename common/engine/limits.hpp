#pragma once
// The one set of per-job limits, configured by whoever runs jobs (server flags,
// CLI defaults). JobLimits is what spec readers check a spec against (a spec over
// a limit is refused up front with a SpecError naming the field, never half-run);
// JobCaps is the part the runner enforces while a job runs, derived from it.
#include <cstddef>
#include <cstdint>
#include <functional>
#include <string>
#include <string_view>

namespace tally {

// Hard caps the runner enforces on one job (samples, compute seconds).
struct JobCaps {
  uint64_t max_samples = 100'000'000'000ULL;
  double max_seconds = 3600.0;
};

struct JobLimits {
  size_t max_dimensions = 64;
  // Dimensions of the embedded lattice the lattice cone rule builds when its spec compiles
  // (a fast CBC over 2^20 points: about 0.1 s of CPU a dimension, tens under sanitizers;
  // the fuzz harness lowers it so that a valid spec stays quick).
  size_t max_embedded_lattice_dimensions = 32;
  // Bytes of one job's state in memory (job_state_bytes, common/engine/job_state.hpp):
  // an image's pixels or a point query's points over it are refused naming the field.
  // This is the engine's fallback; tally-server, tally-worker and `tally run` replace it
  // with half of the machine's memory (server/host/memory_budget.hpp), so that 4K
  // frames fit on an ordinary workstation.
  uint64_t max_state_bytes = uint64_t{4} << 30;
  uint64_t max_samples = 100'000'000'000ULL;
  double max_seconds = 3600.0;
  size_t max_expression_length = 4096;
  uint64_t max_pixels = 4096ULL * 4096ULL;
  uint64_t max_quadrature_points = 1ULL << 26;
  // Components of one vector integrand ("expressions", Genz "families", or the values of
  // a parameterized expression): each costs its own evaluations and ~24 bytes of state a
  // result group; the covariance of the means (m^2 / 2 channels) is only kept when asked.
  size_t max_components = 16384;
  size_t max_table_size = 1 << 20;  // tabulated densities, inline meshes' vertices
  // Triangles of one lighting scene, all meshes together (inline, OBJ, glTF); vertices
  // are bounded by max_vertices below. Memory: ~100 bytes a triangle at peak while the
  // scene is built (docs/performance.md).
  size_t max_triangles = 1 << 20;
  // Decoded texels of one lighting job's textures (12 bytes a texel: linear RGB floats);
  // a scene over it is refused naming the texture that crossed it.
  uint64_t max_texture_bytes = uint64_t{1} << 30;
  // The files a lighting scene names (glTF/GLB, OBJ + .mtl, PNG/JPEG, EXR/HDR) are read
  // by bounded readers (docs/security.md, "Scene files"): each count below is checked
  // from the file's header or a pre-scan, before what it counts is allocated.
  size_t max_vertices = size_t{3} << 20;  // mesh vertices of one scene, after each primitive keeps only those it uses
  size_t max_shapes = 65536;              // shapes: glTF primitive instances, OBJ material groups, inline shapes
  size_t max_gltf_nodes = size_t{1} << 16;  // entries of a glTF's "nodes" (and of its other top-level arrays)
  size_t max_file_json_depth = 64;        // nesting of a glTF's JSON (the .gltf, or a .glb's JSON chunk)
  size_t max_polygon_vertices = 256;      // vertices of one OBJ face (triangulated as a fan of ears)
  size_t max_image_channels = 8;          // channels of one image file (8: tally's own 7-channel EXR reads as a map)
  // Bytes decoding one job's image files may take, all images together: per image
  // width x height x channels x (stored + decoded bytes a sample) + 12 a texel kept,
  // read from the file's header before any pixel is decoded.
  uint64_t max_decode_bytes = uint64_t{1} << 30;
  std::string asset_dir;            // OBJ files for lighting scenes; empty = none allowed
  // The content-addressed asset store ("sha256:<hex>" names in scenes, see
  // common/lighting/asset_resolver.hpp); empty = no store, such names are refused.
  std::string asset_store;
  // Which stored assets the submitter may read (the server sets it per request: a
  // tenant reads the assets it uploaded). Empty: every stored asset. A "sha256:" name
  // it refuses reads exactly as one that is not stored (no existence oracle), wherever
  // the scene names it: in the spec, or inside a glTF or OBJ (buffers, images, mtllib).
  std::function<bool(std::string_view hex)> may_read_asset;

  JobCaps caps() const { return JobCaps{max_samples, max_seconds}; }
};

}  // namespace tally
