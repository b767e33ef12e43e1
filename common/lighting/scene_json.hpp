#pragma once
// The "scene" object of a lighting job spec (format in docs/lighting.md):
//   {"camera": {...}?, "materials": {"name": {...}}, "shapes": [...], "lights": [...]}
// Unknown fields are errors; sizes are checked against JobLimits before anything big
// is allocated; every file the scene names is read through asset_resolver.hpp.
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



}  // namespace tally
