// Bit-identical results whatever the thread count; a scene far from the origin gives
// the same estimate; spec errors name their field.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <future>

#include <filesystem>
#include <fstream>

#include "common/lighting/lighting_counters.hpp"
#include "common/lighting/scene_json.hpp"
#include "common/lighting/asset_resolver.hpp"
#include "common/spec/spec_reader.hpp"
#include "lighting/lighting_test_support.hpp"
#include "support/cornell_box.hpp"

namespace tally::test {
namespace {

json cornell_image_spec() {
  json m = scenes::cornell_materials();
  m["lamp"] = emitter(12.0);
  m["gloss"] = {{"type", "phong"}, {"reflectance", {0.8, 0.8, 0.8}}, {"exponent", 30}};
  json camera = scenes::cornell_camera();
  camera["resolution"] = {40, 30};
  return {{"kind", "lighting"},
          {"seed", 5},
          {"scene", {{"camera", camera}, {"materials", m}, {"shapes", scenes::cornell_shapes("gloss")}}},
          {"query", {{"type", "image"}, {"max_depth", 4}, {"russian_roulette", true}, {"tile_size", 16}}},
          {"estimators", {"mis"}},
          {"stop", {{"max_samples", 24}}}};
}

TEST(Determinism, ImageBitIdenticalOneVsTwoThreads) {
  const json spec = cornell_image_spec();
  const JobRun a = run_spec(spec, 1);
  const JobRun b = run_spec(spec, 2);
  ASSERT_EQ(a.runner->state().channels.size(), b.runner->state().channels.size());
  EXPECT_EQ(test::differing_channels(a, b), 0u);
  EXPECT_TRUE(a.runner->state().counters == b.runner->state().counters);
  EXPECT_EQ(a.runner->state().samples, 24u);
  EXPECT_GT(a.runner->state().channels[0].n, 0u);
  // The snapshot agrees with the channels it reads.
  const ImageSource* img = a.job->image();
  ASSERT_NE(img, nullptr);
  const ImageSnapshot s = img->snapshot(a.runner->state());
  EXPECT_EQ(s.width, 40);
  EXPECT_EQ(s.height, 30);
  EXPECT_EQ(s.samples[0], 24.0f);
}

TEST(Determinism, AdaptiveSamplingSkipsConvergedTiles) {
  json spec = cornell_image_spec();
  spec["query"]["adaptive"] = {{"rel_error", 0.5}, {"min_spp", 4}};
  spec["stop"] = {{"max_samples", 256}};
  const JobRun r = run_spec(spec, 2);
  const auto& ps = r.runner->state().partition_samples;
  const auto [lo, hi] = std::minmax_element(ps.begin(), ps.end());
  EXPECT_LT(*lo, *hi);  // some tiles stopped earlier than others
  EXPECT_GE(*lo, 4u);
}

json translated(json scene, const Vec3& t) {
  for (json& s : scene["shapes"]) {
    for (const char* key : {"corner", "center"}) {
      if (s.contains(key)) s[key] = vec(Vec3{s[key][0], s[key][1], s[key][2]} + t);
    }
  }
  return scene;
}

TEST(Numerics, TranslatedSceneGivesTheSameEstimate) {
  const Vec3 t{1e5, -2e5, 3e5};
  const std::vector<std::string> est = {"uniform_hemisphere", "cosine_hemisphere", "light_area", "mis"};
  json a = point_spec(lecture_scene(), est, 20000);
  json b = point_spec(translated(lecture_scene(), t), est, 20000);
  b["query"]["points"][0]["p"] = vec(t);
  // The receiver point sits on the receiver quad: spawned rays must not re-hit it.
  const JobRun ra = run_spec(a), rb = run_spec(b);
  for (size_t c = 0; c < ra.runner->state().channels.size(); ++c) {
    const Tally &x = ra.channel(c), &y = rb.channel(c);
    EXPECT_LE(std::fabs(x.mean - y.mean), 4 * std::hypot(x.std_error(), y.std_error()) + 1e-12) << c;
    EXPECT_GT(x.mean, 0.0);
  }
}

TEST(Numerics, DegenerateTrianglesAndZeroAreaLightsGiveNoNaN) {
  const json scene = {{"materials", {{"lamp", emitter(2.0)}, {"white", diffuse(0.5)}}},
                      {"shapes", json::array({
                                     {{"type", "mesh"}, {"vertices", {0, 0, 1, 0, 0, 1, 0, 0, 1, 1, 1, 1}}, {"indices", {0, 1, 2, 0, 1, 3}}, {"material", "lamp"}},
                                     {{"type", "disk"}, {"center", {0, 0, 2}}, {"normal", {0, 0, -1}}, {"radius", 0}, {"material", "lamp"}},
                                     {{"type", "quad"}, {"corner", {-1, -1, 3}}, {"edge_u", {2, 0, 0}}, {"edge_v", {2, 0, 0}}, {"material", "lamp"}},
                                     {{"type", "sphere"}, {"center", {0.5, 0.5, 1}}, {"radius", 0.2}, {"material", "white"}},
                                 })}};
  json spec = point_spec(scene, {"uniform_hemisphere", "cosine_hemisphere", "light_area", "mis"}, 4000);
  spec["query"]["max_depth"] = 3;
  const JobRun r = run_spec(spec);
  EXPECT_EQ(r.counter(LightingCounter::nonfinite), 0u);
  for (const Tally& t : r.runner->state().channels) {
    EXPECT_TRUE(std::isfinite(t.mean));
    EXPECT_EQ(t.mean, 0.0);  // every light has zero area
  }
  EXPECT_EQ(plan_json(*r.job)["scene"]["dropped_zero_area_lights"].size(), 3u);
}

std::string spec_error_pointer(const json& spec, const JobLimits& limits = {}) {
  try {
    compile_lighting_job(spec, limits);
  } catch (const SpecError& e) {
    return e.pointer();
  }
  return "<no error>";
}

// The warning says what became of non-finite samples: left out of a tally, counted as
// 0 in an image's replicate sums.
TEST(Numerics, NonfiniteWarningSaysWhereTheSamplesWent) {
  JobState s;
  s.counter_names.assign(lighting_counter_names().begin(), lighting_counter_names().end());
  s.counters.values.assign(s.counter_names.size(), 0);
  EXPECT_TRUE(lighting_counter_warnings(s).empty());
  s.counters.add(static_cast<size_t>(LightingCounter::nonfinite), 3);
  EXPECT_EQ(lighting_counter_warnings(s), std::vector<std::string>{"3 non-finite sample values were excluded"});
  s.sums.assign(24, 0.0f);
  EXPECT_EQ(lighting_counter_warnings(s), std::vector<std::string>{"3 non-finite sample values were counted as 0"});
}

TEST(Spec, ErrorsNameTheField) {
  json base = point_spec(lecture_scene(), {"mis"}, 100);
  json s = base;
  s["scene"]["shapes"][1]["colour"] = 1;
  EXPECT_EQ(spec_error_pointer(s), "/scene/shapes/1/colour");
  s = base;
  s["query"]["points"][0]["material"] = "nope";
  EXPECT_EQ(spec_error_pointer(s), "/query/points/0/material");
  s = base;
  s["estimators"] = {"mis", "bogus"};
  EXPECT_EQ(spec_error_pointer(s), "/estimators/1");
  s = base;
  s["extra"] = true;
  EXPECT_EQ(spec_error_pointer(s), "/extra");
  s = base;  // per-component targets are a vector integrand's (issue 31)
  s["stop"]["component_targets"] = {{"rel_error", {0.1}}};
  EXPECT_EQ(spec_error_pointer(s), "/stop/component_targets");
  s = base;
  s["scene"]["camera"] = {{"position", {0, 0, 5}}, {"look_at", {0, 0, 0}}, {"resolution", {5000, 5000}}};
  JobLimits small;
  small.max_pixels = 1000000;
  EXPECT_EQ(spec_error_pointer(s, small), "/scene/camera/resolution");
  s = base;
  s["query"] = {{"type", "image"}};
  EXPECT_EQ(spec_error_pointer(s), "/scene/camera");
  s = base;
  s["scene"]["shapes"][0] = {{"type", "mesh"}, {"vertices", {0, 0, 0, 1, 0, 0, 0, 1, 0}}, {"indices", {0, 1, 2, 0, 1, 2, 0, 1, 2, 0, 1, 2}}, {"material", "white"}};
  JobLimits tiny;
  tiny.max_triangles = 3;
  EXPECT_EQ(spec_error_pointer(s, tiny), "/scene/shapes/0/indices");
  tiny = JobLimits{};
  tiny.max_table_size = 2;  // the inline mesh's 3 vertices
  EXPECT_EQ(spec_error_pointer(s, tiny), "/scene/shapes/0/vertices");
}

TEST(Spec, AssetPathsCannotEscape) {
  namespace fs = std::filesystem;
  const fs::path root = fs::temp_directory_path() / "tally_asset_escape";
  fs::remove_all(root);
  fs::create_directories(root / "assets");
  { std::ofstream(root / "secret.obj") << "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"; }
  fs::create_symlink(root / "secret.obj", root / "assets" / "link.obj");
  JobLimits limits;
  limits.asset_dir = (root / "assets").string();
  auto spec_for = [&](const std::string& path) {
    json scene = {{"materials", {{"w", diffuse(0.5)}}},
                  {"shapes", json::array({{{"type", "mesh"}, {"obj", path}, {"material", "w"}}})}};
    return point_spec(scene, {"mis"}, 10);
  };
  for (const std::string& bad : std::vector<std::string>{"../secret.obj", (root / "secret.obj").string(), "link.obj", "missing.obj"}) {
    EXPECT_EQ(spec_error_pointer(spec_for(bad), limits), "/scene/shapes/0/obj") << bad;
  }
  EXPECT_EQ(spec_error_pointer(spec_for("x.obj"), JobLimits{}), "/scene/shapes/0/obj");  // no asset dir
  fs::remove_all(root);
}

// The path checks covered the OBJ only: `mtllib ../outside/x.mtl` opened a file
// outside --asset-dir, and a FIFO there blocked the thread forever. Now an OBJ's
// mtllib opens nothing, and the OBJ itself is opened without blocking.
TEST(Spec, ObjMaterialLibrariesOpenNothingAndFifosDoNotBlock) {
  namespace fs = std::filesystem;
  const fs::path root = fs::temp_directory_path() / "tally_asset_mtllib";
  fs::remove_all(root);
  fs::create_directories(root / "assets");
  fs::create_directories(root / "outside");
  const fs::path fifo = root / "outside" / "x.mtl";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  { std::ofstream(root / "assets" / "m.obj") << "mtllib ../outside/x.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl a\nf 1 2 3\n"; }
  ASSERT_EQ(::mkfifo((root / "assets" / "pipe.obj").c_str(), 0600), 0);
  JobLimits limits;
  limits.asset_dir = (root / "assets").string();
  auto spec_for = [&](const std::string& path) {
    json scene = {{"materials", {{"w", diffuse(0.5)}}},
                  {"shapes", json::array({{{"type", "mesh"}, {"obj", path}, {"material", "w"}}})}};
    return point_spec(scene, {"mis"}, 10);
  };
  // Bounded: if the compile blocks on a FIFO, open its other end to free the thread.
  auto bounded = [&](const std::string& obj, const fs::path& unblock) {
    auto f = std::async(std::launch::async, [&] { return spec_error_pointer(spec_for(obj), limits); });
    if (f.wait_for(std::chrono::seconds(10)) == std::future_status::timeout) {
      const int fd = ::open(unblock.c_str(), O_WRONLY | O_NONBLOCK);
      if (fd >= 0) ::close(fd);
      f.get();
      return std::string("blocked");
    }
    return f.get();
  };
  const std::string m = bounded("m.obj", fifo);  // the mtllib is not opened
  EXPECT_NE(m, "blocked");
  EXPECT_NE(m, "/scene/shapes/0/obj") << "the OBJ itself should load";
  EXPECT_EQ(bounded("pipe.obj", root / "assets" / "pipe.obj"), "/scene/shapes/0/obj");
  EXPECT_THROW(read_asset_file(root / "assets" / "pipe.obj", "/p"), SpecError);
  EXPECT_EQ(read_asset_file(root / "assets" / "m.obj", "/p").substr(0, 6), "mtllib");
  EXPECT_THROW(read_asset_file(root / "assets" / "m.obj", "/p", 10), SpecError);  // size cap
  fs::remove_all(root);
}

}  // namespace
}  // namespace tally::test
