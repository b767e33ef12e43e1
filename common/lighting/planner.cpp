#include "common/lighting/planner.hpp"

#include <fmt/format.h>

#include <algorithm>

#include "common/lighting/environment_map.hpp"

namespace tally {

Plan make_plan(const Scene& scene, const PlanQuery& q, bool full) {
  Plan p;
  p.full = full;
  auto add = [&](const char* name, bool& flag, bool needed, std::string why) {
    flag = full || needed;
    p.effects.push_back({name, flag, full && !needed ? "forced on by \"plan\": \"full\" (" + why + ")" : std::move(why)});
  };

  // shadows
  const bool any_nee = std::any_of(q.strategies.begin(), q.strategies.end(), [](Strategy s) {
    return s == Strategy::light_area || s == Strategy::mis;
  });
  const bool delta_lights = !scene.delta_lights.empty();
  const bool nonshape_lights = delta_lights || has_sky(scene);
  const bool all_convex = std::all_of(scene.shapes.begin(), scene.shapes.end(), [](const Shape& s) { return s.convex(); });
  const size_t allowed = (q.image ? 1u : 0u) + (nonshape_lights ? 0u : 1u);
  if (!any_nee && !delta_lights) {
    add("shadow_rays", p.shadows, false, "the hemisphere estimators trace no shadow rays and there are no point or directional lights");
  } else if (all_convex && scene.shapes.size() <= allowed) {
    add("shadow_rays", p.shadows, false,
        fmt::format("nothing can occlude a light: {} convex shape(s), none between a receiver and a light",
                    scene.shapes.size()));
  } else {
    add("shadow_rays", p.shadows, true,
        all_convex ? fmt::format("{} shapes: one may lie between a receiver and a light", scene.shapes.size())
                   : std::string("a non-convex mesh may occlude lights (or itself)"));
  }

  // indirect
  const bool reflective = std::any_of(scene.shapes.begin(), scene.shapes.end(), [&](const Shape& s) {
    return scene.materials[s.material].reflects();
  });
  if (q.max_depth <= 1) {
    add("indirect", p.indirect, false, "max_depth is 1: direct lighting only");
  } else if (!reflective) {
    add("indirect", p.indirect, false, "no shape reflects light (all reflectances are zero)");
  } else {
    add("indirect", p.indirect, true, fmt::format("max_depth {} and reflective shapes", q.max_depth));
  }

  // specular
  bool mirror = std::any_of(scene.shapes.begin(), scene.shapes.end(), [&](const Shape& s) {
    return scene.materials[s.material].is_delta();
  });
  for (uint32_t m : q.point_materials) mirror = mirror || scene.materials[m].is_delta();
  // Glossy surfaces (GGX / metallic-roughness, Phong) are not delta: they need BSDF
  // sampling and light samples (always on), never the specular effect.
  bool glossy = std::any_of(scene.shapes.begin(), scene.shapes.end(), [&](const Shape& s) {
    const MaterialType t = scene.materials[s.material].type;
    return t == MaterialType::metallic_roughness || t == MaterialType::phong;
  });
  for (uint32_t m : q.point_materials) {
    glossy = glossy || scene.materials[m].type == MaterialType::metallic_roughness ||
             scene.materials[m].type == MaterialType::phong;
  }
  std::string specular_why =
      mirror ? "a mirror material is present"
             : (glossy ? "no mirror materials (glossy surfaces are sampled through their lobes, not followed as delta bounces)"
                       : "no mirror materials");
  // Not an effect to switch: a caveat on the error bars. Light that reaches a surface
  // through a narrow glossy lobe (a lamp's image in a polished metal) is found only by a
  // BSDF-sampled bounce that happens to head for it; where that is rare per pixel, the
  // spread of the replicates, none of which found it, is too small (docs/lighting.md,
  // "Coverage on the suite").
  if (q.max_depth >= 2) {
    // The materials in use: one pass over the shapes, then the query points'.
    std::vector<bool> used(scene.materials.size(), false);
    for (const Shape& s : scene.shapes) used[s.material] = true;
    for (uint32_t m : q.point_materials) used[m] = true;
    size_t count = 0;
    double lowest = kNarrowGlossRoughness;
    for (size_t m = 0; m < scene.materials.size(); ++m) {
      const Material& mat = scene.materials[m];
      if (!used[m] || mat.type != MaterialType::metallic_roughness || mat.roughness >= kNarrowGlossRoughness) continue;
      ++count;
      lowest = std::min(lowest, mat.roughness);
    }
    // Counts and roughness only, no names: a glTF scene and the same scene in JSON plan
    // alike (their materials' names differ).
    if (count > 0) {
      specular_why += fmt::format(
          "; light reaching other surfaces through glossy materials of roughness < {} ({}, the lowest {}) is found "
          "by BSDF sampling alone: where few paths find it, low-spp error bars under-cover it",
          kNarrowGlossRoughness, count == 1 ? std::string("1 material") : fmt::format("{} materials", count), lowest);
    }
  }
  add("specular", p.specular, mirror, std::move(specular_why));

  // sky
  const bool sky = sky_emits(scene);
  std::string sky_why = "no sky: rays that miss return 0";
  if (sky && scene.environment) {
    sky_why = fmt::format("the scene has an environment map ({}x{}, importance-sampled, MIS with the BSDF)",
                          scene.environment->width(), scene.environment->height());
    if (const size_t n = scene.environment->negative_texels(); n > 0) {
      sky_why += fmt::format("; {} slightly negative texel value{} (down to {}) read as 0", n, n == 1 ? "" : "s",
                             scene.environment->most_negative());
    }
  } else if (sky) {
    sky_why = "the scene has a sky";
  }
  add("sky", p.sky, sky, std::move(sky_why));

  // emission
  const bool emitters = std::any_of(scene.shapes.begin(), scene.shapes.end(), [&](const Shape& s) {
    return scene.materials[s.material].emits();
  });
  add("emission", p.emission, emitters, emitters ? "emissive shapes are present" : "no shape emits light");

  // light tree (not forced by "full": both selections are exact)
  size_t entries = 0;
  for (const Shape& s : scene.shapes) {
    if (scene.materials[s.material].emits()) entries += s.type == ShapeType::mesh ? s.triangles.size() : 1;
  }
  if (q.light_selection) {
    p.light_tree = *q.light_selection == LightSelection::tree;
    p.effects.push_back({"light_tree", p.light_tree,
                         fmt::format("\"light_selection\": \"{}\" ({} emitter entries)", p.light_tree ? "tree" : "power", entries)});
  } else if (entries > kLightTreeMinEmitters) {
    p.light_tree = true;
    p.effects.push_back({"light_tree", true,
                         fmt::format("{} emitter entries, more than {}: lights chosen by a light hierarchy (power, distance, orientation)",
                                     entries, kLightTreeMinEmitters)});
  }

  // delta light tree (not forced by "full" either: both ways are exact)
  const size_t positioned = positioned_light_count(scene);
  if (positioned > 0) {
    const char* loop = "each point/spot light is added at every vertex (one shadow ray each)";
    const char* tree = "one point/spot light per vertex, chosen by a light hierarchy (power, distance, spot cone)";
    if (q.light_selection) {
      p.delta_light_tree = *q.light_selection == LightSelection::tree;
      p.effects.push_back({"delta_light_tree", p.delta_light_tree,
                           fmt::format("\"light_selection\": \"{}\" ({} point/spot lights): {}",
                                       p.delta_light_tree ? "tree" : "power", positioned, p.delta_light_tree ? tree : loop)});
    } else {
      p.delta_light_tree = positioned > kDeltaLightTreeMinLights;
      p.effects.push_back({"delta_light_tree", p.delta_light_tree,
                           fmt::format("{} point/spot lights, {} {}: {}", positioned,
                                       p.delta_light_tree ? "more than" : "at most", kDeltaLightTreeMinLights,
                                       p.delta_light_tree ? tree : loop)});
    }
  }
  return p;
}

}  // namespace tally
