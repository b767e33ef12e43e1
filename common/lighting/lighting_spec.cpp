#include "common/lighting/lighting_spec.hpp"

#include <fmt/format.h>

#include <cmath>
#include <functional>
#include <limits>

#include "common/spec/pool_field.hpp"
#include "common/spec/spec_reader.hpp"
#include "common/spec/state_limit_error.hpp"
#include "common/engine/job_state.hpp"
#include "common/lighting/compiled_scene.hpp"
#include "common/lighting/image_kernel.hpp"
#include "common/lighting/point_kernel.hpp"
#include "common/lighting/scene_json.hpp"
#include "common/lighting/localize_scene.hpp"
#include "common/spec/stop_rule_json.hpp"
#include "common/stats/confidence.hpp"

namespace tally {

namespace {

const std::vector<std::string> kEstimatorNames = {"uniform_hemisphere", "cosine_hemisphere", "light_area", "mis"};

Strategy strategy_of(const std::string& name) {
  if (name == "uniform_hemisphere") return Strategy::uniform_hemisphere;
  if (name == "cosine_hemisphere") return Strategy::cosine_hemisphere;
  if (name == "light_area") return Strategy::light_area;
  return Strategy::mis;
}

std::string name_of(Strategy s) { return kEstimatorNames[static_cast<size_t>(s)]; }

// "sampler": "sobol" (default) | "independent"; "replicates": K (sobol only, 2..256;
// default 4 for images, 8 for point queries: pixel_sampler.hpp).
SamplerSettings parse_sampler(SpecReader& root, bool image) {
  SamplerSettings s;
  const std::string kind = root.enumeration_or("sampler", "sobol", {"sobol", "independent"});
  s.kind = kind == "independent" ? SamplerKind::independent : SamplerKind::sobol;
  s.replicates = image ? kDefaultImageReplicates : kDefaultPointReplicates;
  if (root.has("replicates")) {
    if (s.kind == SamplerKind::independent) {
      throw SpecError(root.pointer_of("replicates"), "needs \"sampler\": \"sobol\" (independent samples need no replicates)");
    }
    s.replicates = static_cast<uint32_t>(root.integer("replicates", 2, 256));
  }
  if (s.kind == SamplerKind::independent) s.replicates = 1;
  return s;
}

std::vector<Strategy> parse_estimators(SpecReader& root) {
  std::vector<Strategy> out;
  const nlohmann::json* j = root.find("estimators");
  const std::string p = root.pointer_of("estimators");
  if (j == nullptr) return {Strategy::mis};
  if (!j->is_array() || j->empty() || j->size() > kEstimatorNames.size()) {
    throw SpecError(p, "must be a non-empty array of estimator names");
  }
  for (size_t i = 0; i < j->size(); ++i) {
    const auto& e = (*j)[i];
    const std::string ep = json_pointer_append(p, i);
    if (!e.is_string()) throw SpecError(ep, "must be a string");
    const std::string& name = e.get_ref<const std::string&>();
    if (std::find(kEstimatorNames.begin(), kEstimatorNames.end(), name) == kEstimatorNames.end()) {
      throw SpecError(ep, fmt::format("must be one of uniform_hemisphere, cosine_hemisphere, light_area, mis; got \"{}\"", name));
    }
    const Strategy s = strategy_of(name);
    if (std::find(out.begin(), out.end(), s) != out.end()) throw SpecError(ep, "listed twice");
    out.push_back(s);
  }
  return out;
}

}  // namespace

std::unique_ptr<LightingJob> compile_lighting_job(const nlohmann::json& spec, const JobLimits& limits) {
  SpecReader root(spec, "");
  root.string("kind");
  root.string_or("name", "", 200);  // every kind takes a name (docs/jobs.md)
  read_pool(root);                  // and a worker pool (cluster mode)
  const uint64_t seed = root.integer_or("seed", 1, 0, std::numeric_limits<uint64_t>::max());
  StopRule stop_rule;
  const bool full = root.enumeration_or("plan", "auto", {"auto", "full"}) == "full";
  // How next-event estimation chooses area lights: "auto" lets the planner decide
  // (planner.hpp, light_tree), "power" / "tree" force one.
  const std::string light_selection = root.enumeration_or("light_selection", "auto", {"auto", "power", "tree"});
  SpecReader scene_reader = root.object("scene");
  Scene scene = parse_scene(scene_reader, limits);
  const std::vector<Strategy> strategies = parse_estimators(root);
  {
    SpecReader stop = root.object("stop");
    stop_rule = parse_stop_rule(stop, limits);
    if (stop_rule.component_targets) {
      throw SpecError("/stop/component_targets", "only vector integration jobs have components");
    }
  }

  SpecReader q = root.object("query");
  const std::string type = q.enumeration("type", {"points", "image"});
  const SamplerSettings sampler = parse_sampler(root, type == "image");
  const int max_depth = static_cast<int>(q.integer_or("max_depth", 1, 1, 64));
  const bool rr = q.boolean_or("russian_roulette", false);
  PlanQuery pq;
  pq.image = type == "image";
  pq.max_depth = max_depth;
  pq.strategies = strategies;
  if (light_selection != "auto") {
    pq.light_selection = light_selection == "tree" ? LightSelection::tree : LightSelection::power;
  }

  struct RawPoint {
    Vec3 p, n, wo;
    uint32_t material;
  };
  std::vector<RawPoint> raw;
  int tile_size = 32;
  uint64_t max_pass_spp = 64;
  std::optional<AdaptiveSettings> adaptive;
  if (type == "points") {
    const nlohmann::json& pj = q.at("points");
    const std::string pp = q.pointer_of("points");
    if (!pj.is_array() || pj.empty()) throw SpecError(pp, "must be a non-empty array of points");
    constexpr size_t kMaxPoints = 65536;
    if (pj.size() > kMaxPoints) throw SpecError(pp, fmt::format("too many points (limit {})", kMaxPoints));
    const uint64_t need = job_state_bytes(uint64_t{3} * strategies.size() * sampler.k() * pj.size(), 1);
    if (need > limits.max_state_bytes) {
      throw StateLimitError(pp, fmt::format("{} points x {} estimators x 3 colours x {} replicates need {} bytes of job state; "
                                      "the limit is {} bytes",
                                      pj.size(), strategies.size(), sampler.k(), need, limits.max_state_bytes));
    }
    for (size_t i = 0; i < pj.size(); ++i) {
      SpecReader pr(pj[i], json_pointer_append(pp, i));
      RawPoint rp;
      rp.p = read_vec3(pr, "p");
      rp.n = read_direction(pr, "n");
      rp.wo = pr.has("wo") ? read_direction(pr, "wo") : rp.n;
      rp.material = parse_material_ref(pr.at("material"), pr.pointer_of("material"), scene);
      if (scene.materials[rp.material].textured()) {
        throw SpecError(pr.pointer_of("material"), "has textures; a query point has no texture coordinates");
      }
      pr.finish();
      pq.point_materials.push_back(rp.material);
      raw.push_back(rp);
    }
  } else {
    if (!scene.camera) throw SpecError("/scene/camera", "is required for image queries");
    if (strategies.size() != 1) throw SpecError("/estimators", "an image query takes exactly one estimator");
    tile_size = static_cast<int>(q.integer_or("tile_size", 32, 4, 256));
    const uint64_t w = static_cast<uint64_t>(scene.camera->width), h = static_cast<uint64_t>(scene.camera->height);
    const uint64_t ts = static_cast<uint64_t>(tile_size);
    const uint64_t tiles = ((w + ts - 1) / ts) * ((h + ts - 1) / ts);
    // K > 1: a sum (8 bytes) per replicate channel; K = 1: a tally (ImageKernel).
    const uint64_t per_pixel = 3 * sampler.k();
    const uint64_t need = sampler.k() > 1 ? job_state_bytes(0, tiles, per_pixel * w * h) : job_state_bytes(per_pixel * w * h, tiles);
    if (need > limits.max_state_bytes) {
      throw StateLimitError("/scene/camera/resolution",
                      fmt::format("{}x{} pixels x 3 colours x {} replicates need {} bytes of job state; the limit is {} "
                                  "bytes",
                                  w, h, sampler.k(), need, limits.max_state_bytes));
    }
    max_pass_spp = q.integer_or("max_pass_spp", 64, 1, 1 << 16);
    if (q.has("adaptive")) {
      SpecReader a = q.object("adaptive");
      AdaptiveSettings s;
      s.rel_error = a.number("rel_error", 1e-6, 10.0);
      s.min_spp = a.integer_or("min_spp", 16, 2, 1u << 20);
      a.finish();
      adaptive = s;
    }
  }
  q.finish();
  root.finish();

  localize_scene(scene);
  Plan plan = make_plan(scene, pq, full);
  LightingPlan lp;
  lp.image = type == "image";
  for (Strategy s : strategies) lp.estimators.push_back(name_of(s));
  lp.max_depth = max_depth;
  lp.russian_roulette = rr;
  lp.full = plan.full;
  lp.effects = plan.effects;
  lp.sampler = sampler.kind == SamplerKind::independent ? "independent" : "sobol";
  lp.replicates = sampler.k();
  lp.error_bars = sampler.k() > 1 ? "spread of the replicate means, Student t with replicates - 1 dof"
                                  : "sample variance, Student t with n - 1 dof";
  const Vec3 origin = scene.origin;
  lp.scene.triangles = scene.triangle_count();
  lp.scene.textures = scene.textures.size();
  lp.scene.texture_bytes = scene.texture_bytes;
  lp.scene.local_origin = origin;
  std::shared_ptr<const CompiledScene> cs = CompiledScene::build(std::move(scene), std::move(plan));
  lp.scene.shapes = cs->scene.shapes.size();
  lp.scene.sampled_lights = cs->lights->sampled_count();
  lp.scene.delta_lights = cs->scene.delta_lights.size();
  lp.scene.dropped_zero_area_lights = cs->lights->dropped();

  if (type == "points") {
    std::vector<QueryPoint> pts;
    for (const RawPoint& rp : raw) {
      QueryPoint qp;
      qp.world_p = rp.p;
      Vec3 n = rp.n;
      if (dot(n, rp.wo) < 0) n = -n;  // shade the side w_o is on
      qp.vertex = Vertex{rp.p - origin, n, rp.wo, rp.material};
      const Material& m = cs->scene.materials[rp.material];
      if (m.emits() && (m.two_sided || dot(rp.n, rp.wo) > 0)) qp.emission = m.emission;
      pts.push_back(qp);
    }
    const size_t npts = pts.size();
    auto k = std::make_shared<PointKernel>(cs, std::move(pts), strategies, max_depth, rr, seed, sampler);
    lp.channels = k->channel_count();
    lp.channel_layout = kPointChannelLayout;
    lp.points = npts;
    lp.pass_schedule = k->schedule();
    return std::make_unique<LightingJob>(std::move(k), nullptr, stop_rule, seed, std::move(lp));
  }
  auto k = std::make_shared<ImageKernel>(cs, PathSettings{strategies[0], max_depth, rr}, seed, tile_size, max_pass_spp,
                                         adaptive, sampler);
  lp.channels = k->channel_count() + k->sum_count();
  lp.channel_layout = kImageChannelLayout;
  lp.image_size = LightingImagePlan{k->width(), k->height(), tile_size, k->tile_count()};
  lp.pass_schedule = k->schedule();
  lp.error_summary = "mean over channels of the CI half-width (abs) and of half-width / (|mean| + 1e-3 image mean) (rel)";
  lp.adaptive = adaptive;
  return std::make_unique<LightingJob>(nullptr, std::move(k), stop_rule, seed, std::move(lp));
}

}  // namespace tally
