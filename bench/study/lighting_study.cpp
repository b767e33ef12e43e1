// (d) The reflection equation on the lecture's scene (square area light, an occluder
// half in the way, a diffuse receiver): uniform hemisphere, cosine-weighted, light
// sampling and MIS. RMSE against time at a receiver point, the efficiency 1/(sigma^2 t),
// and an image of the scene at equal time per estimator.
#include <fmt/format.h>

#include <cmath>
#include <fstream>

#include "bench/study/study_support.hpp"
#include "common/image/image_io.hpp"
#include "common/protocol/job_kinds.hpp"

namespace tally::study {

namespace {

const std::vector<std::string> kEstimators = {"uniform_hemisphere", "cosine_hemisphere", "light_area", "mis"};

json lecture_scene(bool with_camera) {
  std::ifstream in(std::string(TALLY_SOURCE_DIR) + "/bench/study/scenes/lecture_scene.json");
  if (!in) throw std::runtime_error("cannot read bench/study/scenes/lecture_scene.json");
  json s = json::parse(in);
  if (!with_camera) s.erase("camera");
  return s;
}

// The receiver point: on the floor, in the occluder's penumbra.
json point_spec(const std::vector<std::string>& estimators, const json& stop, uint64_t seed) {
  return {{"kind", "lighting"},
          {"seed", seed},
          {"scene", lecture_scene(false)},
          {"query",
           {{"type", "points"},
            {"points", json::array({{{"p", {0.0, 0.0, 0.0}}, {"n", {0, 0, 1}}, {"material", "white"}}})}}},
          {"estimators", estimators},
          {"stop", stop}};
}

}  // namespace

void run_lighting_study(const Options& o) {
  // Reference: MIS and light sampling, 2^22 samples each (their standard error is
  // reported and is far below every RMSE plotted).
  const uint64_t n_ref = o.quick ? (1u << 18) : (1u << 22);
  const JobRun ref = run_spec(point_spec({"light_area", "mis"}, {{"max_samples", n_ref}}, 99), o.threads);
  const Tally& la = ref.runner->state().channels[0];
  const Tally& mi = ref.runner->state().channels[3];
  // Inverse-variance combination of the two independent-stream estimates.
  const double wl = 1 / (la.std_error() * la.std_error()), wm = 1 / (mi.std_error() * mi.std_error());
  const double exact = (wl * la.mean + wm * mi.mean) / (wl + wm);
  const double exact_se = 1 / std::sqrt(wl + wm);
  log(fmt::format("lighting reference L_o = {:.8g} +- {:.2g}", exact, exact_se));

  Csv conv(o.out / "lighting_convergence.csv",
           {"estimator", "N", "seeds", "rmse", "rel_rmse", "mean_reported_se", "seconds", "reference", "reference_se"});
  const int seeds = o.quick ? 4 : 16;
  const int max_log2 = o.quick ? 12 : 16;
  for (const std::string& e : kEstimators) {
    for (int k = 6; k <= max_log2; ++k) {
      const uint64_t N = uint64_t{1} << k;
      double sq = 0, se = 0, secs = 0;
      for (int s = 1; s <= seeds; ++s) {
        const JobRun r = run_spec(point_spec({e}, {{"max_samples", N}}, static_cast<uint64_t>(s)), o.threads);
        const Estimate est = r.runner->estimate(0);
        sq += (est.mean - exact) * (est.mean - exact);
        se += est.std_error;
        secs += r.compute_seconds();
      }
      const double rmse = std::sqrt(sq / seeds);
      conv.row({e, N, seeds, rmse, rmse / exact, se / seeds, secs / seeds, exact, exact_se});
    }
    log("lighting convergence " + e + " done");
  }

  // Efficiency: one job per estimator (so its time is its own), sigma^2 per sample and
  // seconds per sample from the runner; and the product's own per-estimator figures
  // from one job that runs all four side by side.
  Csv eff(o.out / "lighting_efficiency.csv",
          {"estimator", "samples", "sigma2", "seconds_per_sample", "efficiency", "job_efficiency", "mean", "std_error"});
  const uint64_t n_eff = o.quick ? (1u << 16) : (1u << 20);
  const JobRun all = run_spec(point_spec(kEstimators, {{"max_samples", n_eff}}, 5), o.threads);
  const json all_result = kind_result_json(*all.job, *all.runner);
  for (size_t i = 0; i < kEstimators.size(); ++i) {
    const std::string& e = kEstimators[i];
    const JobRun r = run_spec(point_spec({e}, {{"max_samples", n_eff}}, 7), o.threads);
    const Tally& t = r.runner->state().channels[0];
    const double tps = r.compute_seconds() / static_cast<double>(n_eff);
    const json je = all_result["points"][0]["estimators"][e]["efficiency"];
    eff.row({e, n_eff, t.variance(), tps, t.variance() > 0 ? json(1 / (t.variance() * tps)) : json(nullptr), je,
             t.mean, t.std_error()});
  }
  log("lighting efficiency done");

  // Images at equal time.
  Csv img(o.out / "lighting_images.csv", {"estimator", "seconds", "spp", "mean_rel_error", "png"});
  const double budget = o.quick ? 0.3 : 2.0;
  for (const std::string& e : kEstimators) {
    json spec = {{"kind", "lighting"},
                 {"seed", 1},
                 {"scene", lecture_scene(true)},
                 {"query", {{"type", "image"}, {"max_pass_spp", 4}}},
                 {"estimators", {e}},
                 {"stop", {{"time_budget_s", budget}}}};
    const JobRun r = run_spec(spec, o.threads);
    const std::string png = encode_png(r.job->image()->snapshot(r.runner->state()));
    const std::string name = "lighting_" + e + ".png";
    std::ofstream(o.out / name, std::ios::binary).write(png.data(), static_cast<std::streamsize>(png.size()));
    img.row({e, r.compute_seconds(), r.runner->state().samples, r.runner->error().rel_error, name});
  }
  log("lighting images done");
}

}  // namespace tally::study
