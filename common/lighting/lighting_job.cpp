#include "common/lighting/lighting_job.hpp"

#include <fmt/format.h>

#include <cmath>
#include <functional>
#include <limits>

#include "common/protocol/spec_reader.hpp"
#include "common/lighting/compiled_scene.hpp"
#include "common/lighting/image_kernel.hpp"
#include "common/lighting/point_kernel.hpp"
#include "common/lighting/scene_json.hpp"
#include "common/protocol/stop_rule_json.hpp"
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

nlohmann::json vec_json(const Vec3& v) { return nlohmann::json::array({v.x, v.y, v.z}); }

class LightingJob final : public JobDefinition {
 public:
  std::string_view kind() const override { return "lighting"; }
  std::shared_ptr<const Kernel> kernel() const override { return kernel_; }
  StopRule stop_rule() const override { return stop_; }
  uint64_t seed() const override { return seed_; }
  nlohmann::json plan() const override { return plan_json_; }
  const ImageSource* image() const override { return image_.get(); }

  nlohmann::json result(const JobRunner& runner) const override {
    nlohmann::json r;
    const JobState& st = runner.state();
    const double conf = runner.rule().confidence;
    if (points_) {
      nlohmann::json pts = nlohmann::json::array();
      for (size_t k = 0; k < points_->points().size(); ++k) {
        nlohmann::json est = nlohmann::json::object();
        for (size_t e = 0; e < points_->strategies().size(); ++e) {
          nlohmann::json mean, se, var, lo, hi;
          double var_sum = 0;
          for (int c = 0; c < 3; ++c) {
            const Tally& t = st.channels[points_->channel(e, k, c)];
            const Interval ci = t.n > 1 ? confidence_interval(t, conf) : Interval{};
            mean.push_back(t.mean);
            se.push_back(t.n > 1 ? t.std_error() : 0.0);
            var.push_back(t.n > 1 ? t.variance() : 0.0);
            lo.push_back(ci.lo);
            hi.push_back(ci.hi);
            var_sum += t.n > 1 ? t.variance() : 0.0;
          }
          const double tps = points_->seconds_per_sample(e);
          const double sigma2 = var_sum / 3.0;
          nlohmann::json o = {{"mean", mean}, {"std_error", se}, {"variance", var},
                              {"ci_lo", lo}, {"ci_hi", hi},
                              {"samples", st.channels[points_->channel(e, k, 0)].n},
                              {"seconds_per_sample", tps}};
          // Efficiency 1 / (sigma^2 t): sigma^2 the mean of the RGB variances.
          o["efficiency"] = sigma2 > 0 && tps > 0 ? nlohmann::json(1.0 / (sigma2 * tps)) : nlohmann::json(nullptr);
          est[name_of(points_->strategies()[e])] = o;
        }
        pts.push_back({{"index", k}, {"p", vec_json(points_->points()[k].world_p)}, {"estimators", est}});
      }
      r["points"] = pts;
      r["channel_layout"] = "((estimator * points) + point) * 3 + rgb";
    }
    if (image_) {
      uint64_t lo = std::numeric_limits<uint64_t>::max(), hi = 0;
      for (uint64_t s : st.partition_samples) {
        lo = std::min(lo, s);
        hi = std::max(hi, s);
      }
      const ErrorSummary e = runner.error();
      r["image"] = {{"width", image_->width()}, {"height", image_->height()},
                    {"tile_size", image_->tile_size()}, {"tiles", image_->tile_count()},
                    {"spp_min", lo}, {"spp_max", hi},
                    {"mean_abs_error", e.abs_error}, {"mean_rel_error", e.rel_error},
                    {"channel_layout", "tile-major; pixels row-major within a tile; rgb interleaved"}};
    }
    return r;
  }

  std::string summary_line(const JobRunner& runner) const override {
    if (image_) {
      const ErrorSummary e = runner.error();
      return fmt::format("image {}x{}, {} spp, mean relative error {:.3g}", image_->width(), image_->height(),
                         runner.state().samples, e.rel_error);
    }
    // One line per (point, estimator), estimators side by side on common random numbers.
    const nlohmann::json res = result(runner);
    std::string out;
    const auto& pts = res["points"];
    for (size_t p = 0; p < pts.size() && p < 8; ++p) {
      for (const auto& [name, e] : pts[p]["estimators"].items()) {
        const auto& m = e["mean"];
        const auto& se = e["std_error"];
        out += fmt::format("{}L_o(point {}, {:<18}) = ({:.6g}, {:.6g}, {:.6g}) ± ({:.3g}, {:.3g}, {:.3g})  efficiency 1/(σ²t) {:.3g}",
                           out.empty() ? "" : "\n", p, name, m[0].get<double>(), m[1].get<double>(),
                           m[2].get<double>(), se[0].get<double>(), se[1].get<double>(), se[2].get<double>(),
                           e["efficiency"].is_number() ? e["efficiency"].get<double>() : 0.0);
      }
    }
    if (pts.size() > 8) out += fmt::format("\n... {} more points (see --json)", pts.size() - 8);
    return out;
  }

  std::shared_ptr<const Kernel> kernel_;
  std::shared_ptr<const PointKernel> points_;
  std::shared_ptr<const ImageKernel> image_;
  StopRule stop_;
  uint64_t seed_ = 0;
  nlohmann::json plan_json_;
};

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

std::unique_ptr<JobDefinition> compile_lighting_job(const nlohmann::json& spec, const JobLimits& limits) {
  SpecReader root(spec, "");
  root.string("kind");
  root.string_or("name", "", 200);  // every kind takes a name (docs/jobs.md)
  auto job = std::make_unique<LightingJob>();
  job->seed_ = root.integer_or("seed", 1, 0, std::numeric_limits<uint64_t>::max());
  const bool full = root.enumeration_or("plan", "auto", {"auto", "full"}) == "full";
  SpecReader scene_reader = root.object("scene");
  Scene scene = parse_scene(scene_reader, limits);
  const std::vector<Strategy> strategies = parse_estimators(root);
  {
    SpecReader stop = root.object("stop");
    job->stop_ = parse_stop_rule(stop, limits);
  }

  SpecReader q = root.object("query");
  const std::string type = q.enumeration("type", {"points", "image"});
  const int max_depth = static_cast<int>(q.integer_or("max_depth", 1, 1, 64));
  const bool rr = q.boolean_or("russian_roulette", false);
  PlanQuery pq;
  pq.image = type == "image";
  pq.max_depth = max_depth;
  pq.strategies = strategies;

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
    const size_t max_points = std::min<size_t>(65536, limits.max_channels / (3 * strategies.size()));
    if (pj.size() > max_points) throw SpecError(pp, fmt::format("too many points (limit {})", max_points));
    for (size_t i = 0; i < pj.size(); ++i) {
      SpecReader pr(pj[i], json_pointer_append(pp, i));
      RawPoint rp;
      rp.p = read_vec3(pr, "p");
      rp.n = read_direction(pr, "n");
      rp.wo = pr.has("wo") ? read_direction(pr, "wo") : rp.n;
      rp.material = parse_material_ref(pr.at("material"), pr.pointer_of("material"), scene);
      pr.finish();
      pq.point_materials.push_back(rp.material);
      raw.push_back(rp);
    }
  } else {
    if (!scene.camera) throw SpecError("/scene/camera", "is required for image queries");
    if (strategies.size() != 1) throw SpecError("/estimators", "an image query takes exactly one estimator");
    const uint64_t pixels = static_cast<uint64_t>(scene.camera->width) * static_cast<uint64_t>(scene.camera->height);
    if (3 * pixels > limits.max_channels) {
      throw SpecError("/scene/camera/resolution", fmt::format("{} pixels need {} channels; the limit is {}", pixels,
                                                              3 * pixels, limits.max_channels));
    }
    tile_size = static_cast<int>(q.integer_or("tile_size", 32, 4, 256));
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
  const nlohmann::json plan_effects = plan.to_json();
  const Vec3 origin = scene.origin;
  const size_t triangles = scene.triangle_count();
  std::shared_ptr<const CompiledScene> cs = CompiledScene::build(std::move(scene), std::move(plan));

  nlohmann::json est_names = nlohmann::json::array();
  for (Strategy s : strategies) est_names.push_back(name_of(s));
  nlohmann::json pj = {{"kind", "lighting"},
                       {"query", type},
                       {"estimators", est_names},
                       {"max_depth", max_depth},
                       {"russian_roulette", rr},
                       {"plan", plan_effects},
                       {"scene", {{"shapes", cs->scene.shapes.size()},
                                  {"triangles", triangles},
                                  {"sampled_lights", cs->lights->sampled_count()},
                                  {"delta_lights", cs->scene.delta_lights.size()},
                                  {"dropped_zero_area_lights", cs->lights->dropped()},
                                  {"local_origin", vec_json(origin)}}}};

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
    auto k = std::make_shared<PointKernel>(cs, std::move(pts), strategies, max_depth, rr, job->seed_);
    pj["channels"] = k->channel_count();
    pj["channel_layout"] = "((estimator * points) + point) * 3 + rgb";
    pj["points"] = npts;
    pj["pass_schedule"] = {{"block_samples", k->schedule().block_samples},
                           {"first_pass_samples", k->schedule().first_pass_samples},
                           {"max_pass_samples", k->schedule().max_pass_samples}};
    job->points_ = k;
    job->kernel_ = k;
  } else {
    auto k = std::make_shared<ImageKernel>(cs, PathSettings{strategies[0], max_depth, rr}, job->seed_, tile_size,
                                           max_pass_spp, adaptive);
    pj["channels"] = k->channel_count();
    pj["channel_layout"] = "tile-major; pixels row-major within a tile; rgb interleaved";
    pj["image"] = {{"width", k->width()}, {"height", k->height()}, {"tile_size", tile_size},
                   {"tiles", k->tile_count()}};
    pj["pass_schedule"] = {{"spp_first_pass", 1}, {"spp_per_pass_cap", max_pass_spp},
                           {"spp_per_block", k->schedule().block_samples}};
    pj["error_summary"] = "mean over channels of the CI half-width (abs) and of half-width / (|mean| + 1e-3 image mean) (rel)";
    if (adaptive) pj["adaptive"] = {{"rel_error", adaptive->rel_error}, {"min_spp", adaptive->min_spp}};
    job->image_ = k;
    job->kernel_ = k;
  }
  job->plan_json_ = std::move(pj);
  return job;
}

}  // namespace tally
