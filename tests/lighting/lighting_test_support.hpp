#pragma once
// Runs lighting specs through the production path: JSON -> compile_lighting_job ->
// JobRunner -> run_local -> tallies.
#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <vector>
#include <nlohmann/json.hpp>

#include "common/engine/job_definition.hpp"
#include "common/engine/job_runner.hpp"
#include "common/engine/pass_loop.hpp"
#include "common/lighting/lighting_counters.hpp"
#include "common/lighting/lighting_spec.hpp"
#include "common/lighting/scene_json.hpp"
#include "common/protocol/job_kinds.hpp"
#include "common/spec/spec_reader.hpp"
#include "common/math/vec3.hpp"
#include "common/rng/counter_rng.hpp"

#include <unistd.h>

namespace tally::test {

using json = nlohmann::json;

struct JobRun {
  std::unique_ptr<JobDefinition> job;
  std::unique_ptr<JobRunner> runner;
  const Tally& channel(size_t c) const { return runner->state().channels.at(c); }
  uint64_t counter(LightingCounter c) const { return runner->state().counters[c]; }
};

// A directory of its own per test, removed by the destructor: root/assets is the job's
// --asset-dir, root/outside a place hostile scene files point at (escape tests). The
// process id in the name keeps concurrent test processes apart.
struct AssetSandbox {
  std::filesystem::path root;
  explicit AssetSandbox(const std::string& name)
      : root(std::filesystem::temp_directory_path() / (name + "_" + std::to_string(::getpid()))) {
    std::filesystem::remove_all(root);
    std::filesystem::create_directories(assets());
    std::filesystem::create_directories(outside());
  }
  ~AssetSandbox() {
    std::error_code ec;
    std::filesystem::remove_all(root, ec);
  }
  AssetSandbox(const AssetSandbox&) = delete;
  AssetSandbox& operator=(const AssetSandbox&) = delete;
  std::filesystem::path assets() const { return root / "assets"; }
  std::filesystem::path outside() const { return root / "outside"; }
  JobLimits limits() const {
    JobLimits l;
    l.asset_dir = assets().string();
    return l;
  }
  // Writes `bytes` to root/`rel`, creating its folders.
  void write(const std::filesystem::path& rel, const std::string& bytes) const {
    std::filesystem::create_directories((root / rel).parent_path());
    std::ofstream(root / rel, std::ios::binary) << bytes;
  }
};

// Sums whose bits differ (0: bit-identical; different lengths count every sum of the
// longer one).
inline size_t differing_sums(const std::vector<float>& a, const std::vector<float>& b) {
  if (a.size() != b.size()) return std::max(a.size(), b.size());
  size_t differ = 0;
  for (size_t i = 0; i < a.size(); ++i) differ += std::memcmp(&a[i], &b[i], sizeof(float)) != 0 ? 1 : 0;
  return differ;
}

// Channels (tallies and sums) of `a` and `b` whose count, mean, M2 or sum differ in any
// bit (0: bit-identical; different channel counts count every channel of the longer one).
inline size_t differing_channels(const JobRun& a, const JobRun& b) {
  const auto& ca = a.runner->state().channels;
  const auto& cb = b.runner->state().channels;
  if (ca.size() != cb.size()) return std::max(ca.size(), cb.size());
  size_t differ = differing_sums(a.runner->state().sums, b.runner->state().sums);
  for (size_t i = 0; i < ca.size(); ++i) {
    if (ca[i].n != cb[i].n || std::memcmp(&ca[i].mean, &cb[i].mean, sizeof(double)) != 0 ||
        std::memcmp(&ca[i].m2, &cb[i].m2, sizeof(double)) != 0) {
      ++differ;
    }
  }
  return differ;
}

// The sum of every tally's mean and every sum channel: above 0 when an image got light.
inline double state_total(const JobRun& r) {
  double total = 0;
  for (const Tally& t : r.runner->state().channels) total += t.mean;
  for (double v : r.runner->state().sums) total += v;
  return total;
}

// Specs without "sampler" run with independent samples here: these tests assert
// properties of i.i.d. samples (per-sample variances, 4-se bounds on each channel's own
// standard error). The sobol sampler (the default) is tested in qmc_test.cpp.
inline JobRun run_spec(json spec, unsigned threads = 1, const JobLimits& limits = {}) {
  if (!spec.contains("sampler")) spec["sampler"] = "independent";
  JobRun r;
  r.job = compile_lighting_job(spec, limits);
  r.runner = std::make_unique<JobRunner>(r.job->kernel(), r.job->stop_rule(), JobCaps{});
  LocalRunOptions o;
  o.threads = threads;
  run_local(*r.runner, o);
  return r;
}

// The effect `name` of the job's plan ({"effect", "on", "why"}); null when the plan does
// not list it.
inline json plan_effect(const JobRun& r, const std::string& name) {
  const json plan = plan_json(*r.job);
  for (const json& e : plan["plan"]["effects"]) {
    if (e["effect"] == name) return e;
  }
  return nullptr;
}

// Point i of a fixed pseudo-random sequence (seed), uniform in the box [lo, hi].
inline Vec3 random_point(uint64_t seed, uint64_t i, const Vec3& lo, const Vec3& hi) {
  const SampleRng rng(seed, i);
  return {lo.x + (hi.x - lo.x) * rng.uniform(0), lo.y + (hi.y - lo.y) * rng.uniform(1), lo.z + (hi.z - lo.z) * rng.uniform(2)};
}

// A 24 x 16 image job of the many-light room (bench/many_lights_scene.hpp) seen from its
// front: sobol, MIS, max_depth 2, 16 spp (the light trees' thread bit-identity tests).
inline json room_image_spec(json scene) {
  scene["camera"] = {{"position", {0, 1.5, 5.5}}, {"look_at", {0, 1.2, 0}}, {"fov_deg", 70}, {"resolution", {24, 16}}};
  return {{"kind", "lighting"}, {"seed", 8}, {"sampler", "sobol"}, {"scene", scene},
          {"query", {{"type", "image"}, {"max_depth", 2}, {"tile_size", 8}}},
          {"estimators", {"mis"}}, {"stop", {{"max_samples", 16}}}};
}

// `scene` parsed as a job's "/scene" (throws SpecError naming the field).
inline Scene parse_scene_json(const json& scene, const JobLimits& limits) {
  SpecReader r(scene, "/scene");
  return parse_scene(r, limits);
}

// The SpecError that parsing `scene` raises ("" if none): "pointer: message".
inline std::string scene_error(const json& scene, const JobLimits& limits) {
  try {
    parse_scene_json(scene, limits);
  } catch (const SpecError& e) {
    return e.what();
  }
  return "";
}

inline json vec(const Vec3& v) { return json::array({v.x, v.y, v.z}); }

inline json diffuse(double a) { return {{"type", "diffuse"}, {"albedo", {a, a, a}}}; }
inline json emitter(double l, bool two_sided = false) {
  return {{"type", "emissive"}, {"radiance", {l, l, l}}, {"two_sided", two_sided}};
}

// A point query at the origin, normal +z, diffuse albedo rho.
inline json point_spec(const json& scene, const std::vector<std::string>& estimators, uint64_t samples,
                       double rho = 0.5, uint64_t seed = 7) {
  return {{"kind", "lighting"},
          {"seed", seed},
          {"scene", scene},
          {"query", {{"type", "points"},
                     {"points", json::array({{{"p", {0, 0, 0}}, {"n", {0, 0, 1}}, {"material", diffuse(rho)}}})}}},
          {"estimators", estimators},
          {"stop", {{"max_samples", samples}}}};
}

// Lambert's formula for a polygon above the horizon of (p, n), atan2 form.
inline double lambert_irradiance(const std::vector<Vec3>& poly, const Vec3& p, const Vec3& n, double L) {
  double sum = 0;
  for (size_t i = 0; i < poly.size(); ++i) {
    const Vec3 a = normalize(poly[i] - p), b = normalize(poly[(i + 1) % poly.size()] - p);
    const Vec3 c = cross(a, b);
    const double s = length(c);
    sum += std::atan2(s, dot(a, b)) * dot(n, c / s);
  }
  return 0.5 * L * std::fabs(sum);
}

// The lecture's scene: a receiver, a square area light and an occluder partly between.
inline json lecture_scene() {
  return {{"materials", {{"white", diffuse(0.8)}, {"grey", diffuse(0.3)}, {"lamp", emitter(5.0)}}},
          {"shapes", json::array({
                         {{"type", "quad"}, {"corner", {-3, -3, 0}}, {"edge_u", {6, 0, 0}}, {"edge_v", {0, 6, 0}}, {"material", "white"}},
                         {{"type", "quad"}, {"corner", {-0.5, -0.5, 2}}, {"edge_u", {0, 1, 0}}, {"edge_v", {1, 0, 0}}, {"material", "lamp"}},
                         {{"type", "quad"}, {"corner", {-0.2, -0.6, 1}}, {"edge_u", {0, 0.7, 0}}, {"edge_v", {0.7, 0, 0}}, {"material", "grey"}},
                     })}};
}

}  // namespace tally::test
