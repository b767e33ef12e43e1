// Lighting throughput and estimator efficiency (figures go to docs/lighting.md).
//  1. direct-lighting samples/s on one core (camera ray + one light sample + one shadow
//     ray; light_area, max_depth 1) on a Cornell-box-like scene, vs the rate of bare
//     rtcIntersect1 calls (through Accel) on the same number of incoherent rays;
//  2. the same job on 2 worker threads vs 1;
//  3. the lecture's scene: variance, time per sample and efficiency of each estimator;
//  4. the many-light room (bench/many_lights_scene.hpp, 1,000 emitters): variance per
//     sample of MIS direct lighting at equal samples, light tree vs power selection.
//  5. the same room lit by 1,000 point and spot lights (many_point_lights_scene): time per
//     sample, variance per sample and RMSE at equal time of MIS with max_depth 2, every
//     light added at every vertex (the loop) vs one light per vertex from the light tree.
// `lighting_bench --many-lights-scene FILE` writes the many-light scene as a job spec;
// `lighting_bench --many-point-lights` runs only 5.
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <nlohmann/json.hpp>

#include "bench/many_lights_scene.hpp"
#include "common/engine/pass_loop.hpp"
#include "tests/support/cornell_box.hpp"
#include "common/lighting/accel.hpp"
#include "common/lighting/lighting_spec.hpp"
#include "common/protocol/lighting_json.hpp"
#include "common/lighting/scene_json.hpp"
#include "common/lighting/localize_scene.hpp"
#include "common/rng/counter_rng.hpp"
#include "common/sampling/sphere.hpp"

using namespace tally;
using json = nlohmann::json;

namespace {

json cornell_scene() {
  json camera = scenes::cornell_camera();
  camera["resolution"] = {256, 256};
  json shapes = scenes::cornell_shapes("white");
  shapes.push_back({{"type", "quad"}, {"corner", {0.1, 0, 0.0}}, {"edge_u", {0.5, 0, 0}}, {"edge_v", {0, 0.7, 0.2}}, {"material", "white"}});
  return {{"camera", camera}, {"materials", scenes::cornell_materials()}, {"shapes", shapes}};
}

struct Timed {
  double seconds;
  uint64_t camera_rays, shadow_rays;
};

Timed run_direct(unsigned threads, uint64_t spp) {
  const json spec = {{"kind", "lighting"}, {"seed", 1}, {"scene", cornell_scene()},
                     {"query", {{"type", "image"}, {"max_depth", 1}}}, {"estimators", {"light_area"}},
                     {"stop", {{"max_samples", spp}}}};
  auto job = compile_lighting_job(spec, JobLimits{});
  JobRunner runner(job->kernel(), job->stop_rule(), JobCaps{});
  LocalRunOptions o;
  o.threads = threads;
  const auto t0 = std::chrono::steady_clock::now();
  run_local(runner, o);
  const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return {s, runner.state().counters[LightingCounter::camera_rays], runner.state().counters[LightingCounter::shadow_rays]};
}

double bare_rays(uint64_t n) {
  const json scene_json = cornell_scene();  // SpecReader keeps a reference
  SpecReader r(scene_json, "/scene");
  Scene scene = parse_scene(r, JobLimits{});
  localize_scene(scene);
  const Accel accel(scene);
  uint64_t hits = 0;
  const auto t0 = std::chrono::steady_clock::now();
  for (uint64_t i = 0; i < n; ++i) {
    const SampleRng rng(3, i);
    // Incoherent: random origins inside the box, random directions.
    const Vec3 o = Vec3{-0.95 + 1.9 * rng.uniform(0), 0.05 + 1.9 * rng.uniform(1), -0.95 + 1.9 * rng.uniform(2)} - scene.origin;
    const Vec3 d = sample_uniform_sphere({rng.uniform(3), rng.uniform(4)});
    hits += accel.intersect(o, d, 1e30).has_value() ? 1 : 0;
  }
  const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  if (hits == 0) std::printf("(no hits?)\n");
  return s;
}

// The many-light room as a job spec: MIS direct lighting at four receivers spread over
// the room (floor centre, floor corner, a wall, a pillar top), independent samples.
json many_lights_spec(const std::string& selection, uint64_t samples) {
  const json white = scenes::cornell_diffuse(0.5, 0.5, 0.5);
  return {{"kind", "lighting"}, {"seed", 7}, {"sampler", "independent"}, {"light_selection", selection},
          {"scene", scenes::many_lights_scene(1000)},
          {"query", {{"type", "points"}, {"max_depth", 1},
                     {"points", json::array({{{"p", {1.0, 0, 1.0}}, {"n", {0, 1, 0}}, {"material", white}},
                                             {{"p", {-5.5, 0, 5.5}}, {"n", {0, 1, 0}}, {"material", white}},
                                             {{"p", {5.9, 1.0, 0.0}}, {"n", {-1, 0, 0}}, {"material", white}},
                                             {{"p", {2.0, 1.2, 0.0}}, {"n", {0, 1, 0}}, {"material", white}}})}}},
          {"estimators", {"mis"}}, {"stop", {{"max_samples", samples}}}};
}

void many_lights_line() {
  const uint64_t n = 20000;
  std::printf("\nmany-light room (1,000 emitters, bench/many_lights_scene.hpp), MIS direct lighting, 4 points, %llu samples each\n",
              static_cast<unsigned long long>(n));
  std::printf("  %-6s %-10s %-10s %-12s %-12s %s\n", "point", "selection", "mean(G)", "std_err", "var/sample", "s/sample");
  double sum_ratio = 0;
  for (size_t pt = 0; pt < 4; ++pt) {
    double var[2] = {0, 0}, t[2] = {0, 0};
    int k = 0;
    for (const char* sel : {"power", "tree"}) {
      auto job = compile_lighting_job(many_lights_spec(sel, n), JobLimits{});
      JobRunner runner(job->kernel(), job->stop_rule(), JobCaps{});
      run_local(runner, LocalRunOptions{});
      const json res = lighting_result_json(job->result(runner));
      const json& e = res["points"][pt]["estimators"]["mis"];
      var[k] = e["variance"][1].get<double>();
      t[k++] = e["seconds_per_sample"].get<double>();
      std::printf("  %-6zu %-10s %-10.5g %-12.3g %-12.4g %.3g\n", pt, sel, e["mean"][1].get<double>(), e["std_error"][1].get<double>(),
                  e["variance"][1].get<double>(), e["seconds_per_sample"].get<double>());
    }
    std::printf("  point %zu: variance per sample tree / power = %.3f; time to equal error (var x s/sample) tree / power = %.3f\n",
                pt, var[1] / var[0], var[1] * t[1] / (var[0] * t[0]));
    sum_ratio += var[1] / var[0];
  }
  std::printf("  mean variance ratio tree / power at equal samples: %.3f\n", sum_ratio / 4);
}

// The room with 1,000 point/spot lights: MIS, max_depth 2 (so the loop has variance
// too: the indirect bounce), at the four receivers of many_lights_spec, independent
// samples; "power" keeps the loop over every light, "tree" picks one per vertex.
json many_point_lights_spec(const std::string& selection, uint64_t samples, uint64_t seed) {
  json spec = many_lights_spec(selection, samples);
  spec["seed"] = seed;
  spec["scene"] = scenes::many_point_lights_scene(1000);
  spec["query"]["max_depth"] = 2;
  return spec;
}

// Loop and tree jobs interleaved (loop, tree, loop, tree, ...; `rounds` of each, new seed
// each round) on one thread; per receiver the pooled variance per sample and time per
// sample of each, then the ratios.
void many_point_lights_line() {
  const int rounds = 3;
  const uint64_t n_loop = 1000, n_tree = 50000;
  std::printf("\nroom with 1,000 point/spot lights (bench/many_lights_scene.hpp), MIS max_depth 2, 4 points, 1 thread,\n"
              "  %d interleaved rounds: loop over all lights %llu samples/round, light tree %llu samples/round\n",
              rounds, static_cast<unsigned long long>(n_loop), static_cast<unsigned long long>(n_tree));
  double var[2][4] = {}, mean[2][4] = {}, secs[2][4] = {};
  uint64_t shadow[2] = {0, 0}, samples[2] = {0, 0};
  for (int r = 0; r < rounds; ++r) {
    int k = 0;
    for (const char* sel : {"power", "tree"}) {
      const uint64_t n = k == 0 ? n_loop : n_tree;
      auto job = compile_lighting_job(many_point_lights_spec(sel, n, 100 + static_cast<uint64_t>(r)), JobLimits{});
      JobRunner runner(job->kernel(), job->stop_rule(), JobCaps{});
      run_local(runner, LocalRunOptions{});
      const json res = lighting_result_json(job->result(runner));
      for (size_t pt = 0; pt < 4; ++pt) {
        const json& e = res["points"][pt]["estimators"]["mis"];
        var[k][pt] += e["variance"][1].get<double>() / rounds;
        mean[k][pt] += e["mean"][1].get<double>() / rounds;
        secs[k][pt] += e["seconds_per_sample"].get<double>() / rounds;
      }
      shadow[k] += runner.state().counters[LightingCounter::shadow_rays];
      samples[k] += 4 * n;
      ++k;
    }
  }
  std::printf("  shadow rays per sample: loop %.1f, tree %.2f\n", static_cast<double>(shadow[0]) / static_cast<double>(samples[0]),
              static_cast<double>(shadow[1]) / static_cast<double>(samples[1]));
  std::printf("  %-6s %-22s %-22s %-14s %-14s %s\n", "point", "mean(G) loop", "mean(G) tree", "s/sample l/t", "var/sample t/l",
              "RMSE at equal time t/l");
  double log_speed = 0, log_rmse = 0;
  for (size_t pt = 0; pt < 4; ++pt) {
    const double se_l = std::sqrt(var[0][pt] / (rounds * n_loop)), se_t = std::sqrt(var[1][pt] / (rounds * n_tree));
    const double speed = secs[0][pt] / secs[1][pt];
    const double rmse = std::sqrt(var[1][pt] * secs[1][pt] / (var[0][pt] * secs[0][pt]));
    std::printf("  %-6zu %-9.5g +- %-9.2g %-9.5g +- %-9.2g %-14.1f %-14.2f %.3f\n", pt, mean[0][pt], se_l, mean[1][pt], se_t,
                speed, var[1][pt] / var[0][pt], rmse);
    log_speed += std::log(speed) / 4;
    log_rmse += std::log(rmse) / 4;
  }
  std::printf("  geometric mean: time per sample loop / tree %.1f; RMSE at equal time tree / loop %.3f\n", std::exp(log_speed),
              std::exp(log_rmse));
}

}  // namespace

int main(int argc, char** argv) {
  if (argc == 3 && std::strcmp(argv[1], "--many-lights-scene") == 0) {
    std::ofstream(argv[2]) << many_lights_spec("auto", 4096).dump(1) << "\n";
    std::printf("wrote %s\n", argv[2]);
    return 0;
  }
  if (argc == 2 && std::strcmp(argv[1], "--many-point-lights") == 0) {
    many_point_lights_line();
    return 0;
  }
  if (argc == 2 && std::strcmp(argv[1], "--many-lights") == 0) {
    many_lights_line();
    return 0;
  }
  const uint64_t spp = 16;
  run_direct(1, 1);  // warm up (Embree device, page faults)
  const Timed one = run_direct(1, spp);
  const Timed two = run_direct(2, spp);
  const uint64_t samples = one.camera_rays;
  const uint64_t rays = one.camera_rays + one.shadow_rays;
  const double bare = bare_rays(rays);
  std::printf("direct lighting, 256x256 x %llu spp, light_area, max_depth 1\n", static_cast<unsigned long long>(spp));
  std::printf("  1 thread : %.3f s, %.3g samples/s, %.3g rays/s (%llu camera + %llu shadow rays)\n", one.seconds,
              static_cast<double>(samples) / one.seconds, static_cast<double>(rays) / one.seconds,
              static_cast<unsigned long long>(one.camera_rays), static_cast<unsigned long long>(one.shadow_rays));
  std::printf("  bare Embree (Accel::intersect, incoherent): %llu rays in %.3f s = %.3g rays/s\n",
              static_cast<unsigned long long>(rays), bare, static_cast<double>(rays) / bare);
  std::printf("  ratio (bare time / sample time for the same rays): %.2f  (goal >= 0.5)\n", bare / one.seconds);
  std::printf("  2 threads: %.3f s, speed-up %.2fx (goal >= 1.8x)\n", two.seconds, one.seconds / two.seconds);

  std::printf("\nlecture scene (area light, occluder, receiver), point (0,0,0), 400k samples each\n");
  json spec = json::parse(R"({"kind":"lighting","seed":1,"estimators":["uniform_hemisphere","cosine_hemisphere","light_area","mis"],
    "query":{"type":"points","points":[{"p":[0,0,0],"n":[0,0,1],"material":"white"}]},"stop":{"max_samples":400000}})");
  spec["scene"] = {{"materials", {{"white", scenes::cornell_diffuse(0.8, 0.8, 0.8)}, {"grey", scenes::cornell_diffuse(0.3, 0.3, 0.3)},
                                  {"lamp", {{"type", "emissive"}, {"radiance", {5, 5, 5}}}}}},
                   {"shapes", json::array({
                                  {{"type", "quad"}, {"corner", {-3, -3, 0}}, {"edge_u", {6, 0, 0}}, {"edge_v", {0, 6, 0}}, {"material", "white"}},
                                  {{"type", "quad"}, {"corner", {-0.5, -0.5, 2}}, {"edge_u", {0, 1, 0}}, {"edge_v", {1, 0, 0}}, {"material", "lamp"}},
                                  {{"type", "quad"}, {"corner", {-0.2, -0.6, 1}}, {"edge_u", {0, 0.7, 0}}, {"edge_v", {0.7, 0, 0}}, {"material", "grey"}},
                              })}};
  auto job = compile_lighting_job(spec, JobLimits{});
  JobRunner runner(job->kernel(), job->stop_rule(), JobCaps{});
  run_local(runner, LocalRunOptions{});
  const json res = lighting_result_json(job->result(runner));
  std::printf("  %-20s %-12s %-12s %-12s %-14s %s\n", "estimator", "mean(R)", "std_err", "variance", "s/sample", "efficiency 1/(var t)");
  for (auto it = res["points"][0]["estimators"].begin(); it != res["points"][0]["estimators"].end(); ++it) {
    const json& e = it.value();
    std::printf("  %-20s %-12.6g %-12.3g %-12.4g %-14.3g %.4g\n", it.key().c_str(), e["mean"][0].get<double>(),
                e["std_error"][0].get<double>(), e["variance"][0].get<double>(), e["seconds_per_sample"].get<double>(),
                e["efficiency"].is_null() ? 0.0 : e["efficiency"].get<double>());
  }
  many_lights_line();
  many_point_lights_line();
  return 0;
}
