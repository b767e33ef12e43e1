#pragma once
// Everything the lighting kernels share read-only: the localized scene, its Embree
// acceleration structure, the light set, the point/spot light tree (when the plan has
// it), the plan and the path tracer over them.
// Built once per job; never moved (the parts reference each other).
#include <memory>

#include "common/lighting/accel.hpp"
#include "common/lighting/delta_light_tree.hpp"
#include "common/lighting/light_set.hpp"
#include "common/lighting/path_tracer.hpp"
#include "common/lighting/planner.hpp"
#include "common/lighting/scene.hpp"

namespace tally {

struct CompiledScene {
  Scene scene;
  Plan plan;
  std::unique_ptr<Accel> accel;
  std::unique_ptr<LightSet> lights;
  std::unique_ptr<DeltaLightTree> delta_tree;  // point and spot lights, when plan.delta_light_tree
  std::unique_ptr<PathTracer> tracer;

  // Takes a localized scene (localize_scene) and its plan; builds Embree and the lights.
  static std::shared_ptr<const CompiledScene> build(Scene scene, Plan plan) {
    auto cs = std::make_shared<CompiledScene>();
    cs->scene = std::move(scene);
    cs->plan = std::move(plan);
    cs->accel = std::make_unique<Accel>(cs->scene);
    cs->lights = std::make_unique<LightSet>(cs->scene, cs->plan.light_tree ? LightSelection::tree : LightSelection::power);
    if (cs->plan.delta_light_tree) cs->delta_tree = std::make_unique<DeltaLightTree>(cs->scene);
    cs->tracer = std::make_unique<PathTracer>(cs->scene, *cs->accel, *cs->lights, cs->plan, cs->delta_tree.get());
    return cs;
  }
};

}  // namespace tally
