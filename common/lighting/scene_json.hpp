#pragma once
// The "scene" object of a lighting job spec (format in docs/lighting.md):
//   {"camera": {...}?, "materials": {"name": {...}}, "shapes": [...], "lights": [...]}
// Unknown fields are errors; sizes are checked against JobLimits before anything big
// is allocated; OBJ files load only from inside JobLimits::asset_dir.
#include <filesystem>
#include <string>

#include "common/engine/limits.hpp"
#include "common/spec/spec_reader.hpp"
#include "common/lighting/gltf_scene.hpp"
#include "common/lighting/scene.hpp"
#include "common/lighting/scene_bounds.hpp"

namespace tally {

Scene parse_scene(SpecReader& scene, const JobLimits& limits);

// A material given by name (into scene.materials) or inline as an object (appended).
uint32_t parse_material_ref(const nlohmann::json& j, const std::string& pointer, Scene& scene);

Vec3 read_vec3(SpecReader& r, std::string_view key);
Vec3 read_direction(SpecReader& r, std::string_view key);  // normalised, non-zero

// Resolves `relative` inside `asset_dir`: no absolute paths, no "..", and no symlink
// that leads outside. Throws SpecError(pointer) otherwise.
std::filesystem::path resolve_asset(const std::string& asset_dir, const std::string& relative,
                                    const std::string& pointer);

// The bytes of a file resolve_asset returned: opened without following a symlink
// and without blocking, and only if it is a regular file of at most `max_bytes`.
// Every file a scene causes to be read goes through resolve_asset and this.
std::string read_asset_file(const std::filesystem::path& path, const std::string& pointer,
                            size_t max_bytes = size_t{1} << 30);

// The reader every file a scene names goes through (OBJ, .mtl, glTF and its buffers):
// read_scene_file (asset_resolver.hpp: "sha256:<hex>" from the asset store, or a path
// inside limits.asset_dir; regular files only, no escape, never blocking).
AssetReader scene_asset_reader(const JobLimits& limits);

// Moves the scene into its local frame (see scene.hpp) and returns the translation.
void localize_scene(Scene& scene);


}  // namespace tally
