#pragma once
// Wavefront OBJ meshes and their .mtl materials (docs/lighting.md, "OBJ materials"),
// read with Debian's tinyobjloader after a bounded pre-scan of the OBJ text
// (docs/security.md, "Scene files"): every number must be finite, every face index an
// integer that names a vertex already given, and the counts (vertices, triangles,
// polygon corners, material groups) within JobLimits before tinyobjloader allocates
// anything. Errors are SpecErrors at the scene's pointer naming the file and its line.
#include <optional>
#include <string>
#include <vector>

#include "common/engine/limits.hpp"
#include "common/lighting/gltf_scene.hpp"
#include "common/lighting/scene.hpp"

namespace tally {

// Loads an OBJ into one shape per material group, each keeping only the vertices its
// faces use. With `material` set (the scene names one) every face gets it and `mtllib`
// opens nothing; otherwise the .mtl files it names are read through `read` (relative to
// the OBJ's directory, with the same checks as every asset) and each face gets its
// `usemtl` material (appended to scene.materials, textures to scene.textures).
std::vector<Shape> load_obj(const std::string& relative, const std::string& pointer, const AssetReader& read,
                            const JobLimits& limits, std::optional<uint32_t> material, Scene& scene);

}  // namespace tally
