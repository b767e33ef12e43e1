#include "common/protocol/lighting_json.hpp"

namespace tally {

using nlohmann::json;

namespace {
json vec_json(const Vec3& v) { return json::array({v.x, v.y, v.z}); }
json rgb_json(const std::array<double, 3>& v) { return json::array({v[0], v[1], v[2]}); }
}  // namespace

json lighting_plan_json(const LightingPlan& p) {
  json effects = json::array();
  for (const PlanEffect& e : p.effects) effects.push_back({{"effect", e.name}, {"on", e.on}, {"why", e.why}});
  json j = {{"kind", "lighting"},
            {"query", p.image ? "image" : "points"},
            {"estimators", p.estimators},
            {"max_depth", p.max_depth},
            {"russian_roulette", p.russian_roulette},
            {"plan", {{"mode", p.full ? "full" : "auto"}, {"effects", effects}}},
            {"sampler", {{"type", p.sampler}, {"replicates", p.replicates}, {"error_bars", p.error_bars}}},
            {"scene", {{"shapes", p.scene.shapes},
                       {"triangles", p.scene.triangles},
                       {"sampled_lights", p.scene.sampled_lights},
                       {"delta_lights", p.scene.delta_lights},
                       {"dropped_zero_area_lights", p.scene.dropped_zero_area_lights},
                       {"local_origin", vec_json(p.scene.local_origin)}}},
            {"channels", p.channels},
            {"channel_layout", p.channel_layout}};
  if (p.scene.textures > 0) {  // absent without textures (older plans keep their bytes)
    j["scene"]["textures"] = {{"count", p.scene.textures}, {"decoded_bytes", p.scene.texture_bytes}};
  }
  const PassSchedule& s = p.pass_schedule;
  if (p.image) {
    j["pass_schedule"] = {{"spp_first_pass", s.first_pass_samples},
                          {"spp_per_pass_cap", s.max_pass_samples},
                          {"spp_per_block", s.block_samples}};
  } else {
    j["pass_schedule"] = {{"block_samples", s.block_samples},
                          {"first_pass_samples", s.first_pass_samples},
                          {"max_pass_samples", s.max_pass_samples}};
  }
  if (p.points) j["points"] = *p.points;
  if (p.image_size) {
    j["image"] = {{"width", p.image_size->width},
                  {"height", p.image_size->height},
                  {"tile_size", p.image_size->tile_size},
                  {"tiles", p.image_size->tiles}};
  }
  if (p.error_summary) j["error_summary"] = *p.error_summary;
  if (p.adaptive) j["adaptive"] = {{"rel_error", p.adaptive->rel_error}, {"min_spp", p.adaptive->min_spp}};
  return j;
}

json lighting_result_json(const LightingResult& r) {
  json j;
  if (r.points) {
    json pts = json::array();
    for (const PointResult& pr : *r.points) {
      json est = json::object();
      for (const PointEstimate& e : pr.estimates) {
        json o = {{"mean", rgb_json(e.mean)},
                  {"std_error", rgb_json(e.std_error)},
                  {"variance", rgb_json(e.variance)},
                  {"ci_lo", rgb_json(e.ci_lo)},
                  {"ci_hi", rgb_json(e.ci_hi)},
                  {"samples", e.samples},
                  {"seconds_per_sample", e.seconds_per_sample}};
        o["efficiency"] = e.efficiency ? json(*e.efficiency) : json(nullptr);
        est[e.estimator] = o;
      }
      pts.push_back({{"index", pr.index}, {"p", vec_json(pr.p)}, {"estimators", est}});
    }
    j["points"] = pts;
    j["channel_layout"] = kPointChannelLayout;
  }
  if (r.image) {
    const LightingImageResult& im = *r.image;
    j["image"] = {{"width", im.width},
                  {"height", im.height},
                  {"tile_size", im.tile_size},
                  {"tiles", im.tiles},
                  {"spp_min", im.spp_min},
                  {"spp_max", im.spp_max},
                  {"mean_abs_error", im.mean_abs_error},
                  {"mean_rel_error", im.mean_rel_error},
                  {"channel_layout", kImageChannelLayout}};
  }
  return j;
}

json lighting_spec_as_of(json spec, uint32_t results_version) {
  const auto q = spec.find("query");
  const bool image = q != spec.end() && q->is_object() && q->value("type", json()) == "image";
  if (results_version < 5 && image && !spec.contains("replicates") && spec.value("sampler", json("sobol")) == "sobol") {
    spec["replicates"] = 8;
  }
  return spec;
}

}  // namespace tally
