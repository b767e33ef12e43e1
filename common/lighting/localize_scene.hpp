#pragma once
// A parsed scene moved into its local frame (scene.hpp): centred on its bounds, every
// position rounded to float, as the accelerator and the lights will see it.
#include "common/lighting/scene.hpp"

namespace tally {

// Moves the scene into its local frame (the translation is kept in scene.origin).
void localize_scene(Scene& scene);

}  // namespace tally
