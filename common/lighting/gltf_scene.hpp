#pragma once
// glTF 2.0 scenes (.gltf with external or data-URI buffers, and .glb) read with Debian's
// tinygltf, appended to a tally Scene: the default scene's node hierarchy with its
// transforms (matrix or TRS), indexed triangle primitives (POSITION, NORMAL as shading
// normals, TEXCOORD_0), perspective cameras, KHR_lights_punctual (point, spot,
// directional), and materials (metallic-roughness, emissiveFactor,
// KHR_materials_emissive_strength, KHR_materials_specular; glTF's reference BRDF by
// default, Material::model) and the sampler filters (NEAREST or bilinear). The mapping is documented in docs/lighting.md, "glTF".
//
// Every file the glTF names is read through `read` (the scene's checked asset reader: no
// escape from the asset directory, regular files only, never blocking); tinygltf's own
// file system, path expansion and image decoding are replaced. Errors are SpecErrors at
// the scene's pointer whose message names the glTF field (its JSON pointer inside the file).
#include <functional>
#include <optional>
#include <string>
#include <variant>

#include "common/engine/limits.hpp"
#include "common/lighting/asset_resolver.hpp"
#include "common/lighting/scene.hpp"

namespace tally {

struct GltfRequest {
  std::string file;      // relative path of the .gltf / .glb
  std::string pointer;   // JSON pointer of the "file" field, for messages
  // The camera to take (index into the glTF's cameras, or its name) and the resolution
  // to render it at; none: the scene keeps its own camera (or has none).
  std::optional<std::variant<size_t, std::string>> camera;
  std::string camera_pointer;
  int width = 0, height = 0;
};

void load_gltf(Scene& scene, const GltfRequest& request, const AssetReader& read, const JobLimits& limits);

}  // namespace tally
