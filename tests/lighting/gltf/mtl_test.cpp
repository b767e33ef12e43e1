// OBJ .mtl materials (scene_json.cpp): without a "material" in the scene, an OBJ's
// mtllib files are read through the scene's checked reader and each face gets its
// usemtl material (Kd -> albedo, Ks/Ns -> Phong lobe, Ke -> emission); ../ escapes,
// FIFOs and unknown materials fail with errors at the shape's "obj" field.
#include <gtest/gtest.h>

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <future>

#include "common/lighting/scene_json.hpp"
#include "lighting/lighting_test_support.hpp"

namespace tally {
namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;
// A scene parsed as a job's "/scene", and the SpecError it raises ("" if none).
constexpr auto* parse = &test::parse_scene_json;
constexpr auto* error_of = &test::scene_error;
using Dir = test::AssetSandbox;

const char* kObj =
    "mtllib lib.mtl\n"
    "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\n"
    "usemtl matte\nf 1 2 3\n"
    "usemtl shiny\nf 1 3 4\n"
    "usemtl lamp\nf 1 5 6\n"
    "usemtl matte\nf 2 3 6\n";

const char* kMtl =
    "newmtl matte\nKd 0.5 0.25 0.125\nKs 0 0 0\n"
    "newmtl shiny\nKd 0.6 0.6 0.6\nKs 0.6 0.2 0.2\nNs 40\n"
    "newmtl lamp\nKd 0 0 0\nKs 0 0 0\nKe 2 3 4\n";

json obj_scene(const std::string& path) { return {{"shapes", json::array({{{"type", "mesh"}, {"obj", path}}})}}; }

TEST(Mtl, MaterialsMapTermByTerm) {
  Dir d("tally_mtl_map");
  d.write("assets/m/a.obj", kObj);
  d.write("assets/m/lib.mtl", kMtl);
  const Scene s = parse(obj_scene("m/a.obj"), d.limits());
  ASSERT_EQ(s.shapes.size(), 3u);  // one shape per material, in order of first use
  ASSERT_EQ(s.materials.size(), 3u);
  EXPECT_EQ(s.shapes[0].triangles.size(), 2u);  // both "matte" faces
  const Material& matte = s.materials[s.shapes[0].material];
  EXPECT_EQ(matte.type, MaterialType::diffuse);
  EXPECT_EQ(matte.name, "m/a.obj#matte");
  EXPECT_NEAR(matte.albedo.y, 0.25, 1e-7);
  // Kd + Ks = 1.2 in red: both scaled by 1 / 1.2.
  const Material& shiny = s.materials[s.shapes[1].material];
  EXPECT_EQ(shiny.type, MaterialType::phong);
  EXPECT_NEAR(shiny.albedo.x, 0.5, 1e-7);
  EXPECT_NEAR(shiny.reflectance.x, 0.5, 1e-7);
  EXPECT_NEAR(shiny.reflectance.y, 0.2 / 1.2, 1e-7);
  EXPECT_EQ(shiny.exponent, 40.0);
  const Material& lamp = s.materials[s.shapes[2].material];
  EXPECT_EQ(lamp.type, MaterialType::emissive);
  EXPECT_TRUE(lamp.emits());
  EXPECT_EQ(lamp.emission.z, 4.0);
  // A scene "material" still overrides the .mtl (and then mtllib opens nothing).
  json over = obj_scene("m/a.obj");
  over["shapes"][0]["material"] = {{"type", "diffuse"}, {"albedo", {0.5, 0.5, 0.5}}};
  const Scene o = parse(over, d.limits());
  ASSERT_EQ(o.shapes.size(), 1u);
  EXPECT_EQ(o.shapes[0].triangles.size(), 4u);
}

TEST(Mtl, EmitterFromMtlRendersLikeTheJsonMaterial) {
  // The same OBJ quad light: Ke from its .mtl vs an emissive material in the scene JSON.
  Dir d("tally_mtl_render");
  const std::string quad = "v -0.5 -0.5 2\nv -0.5 0.5 2\nv 0.5 0.5 2\nv 0.5 -0.5 2\nusemtl lamp\nf 1 2 3\nf 1 3 4\n";
  d.write("assets/lamp.obj", "mtllib lamp.mtl\n" + quad);
  d.write("assets/lamp.mtl", "newmtl lamp\nKd 0 0 0\nKe 3 2 1\n");
  const json from_mtl = obj_scene("lamp.obj");
  json from_json = obj_scene("lamp.obj");
  from_json["shapes"][0]["material"] = {{"type", "emissive"}, {"radiance", {3, 2, 1}}};
  const test::JobRun a = test::run_spec(test::point_spec(from_mtl, {"mis", "light_area"}, 2000), 1, d.limits());
  const test::JobRun b = test::run_spec(test::point_spec(from_json, {"mis", "light_area"}, 2000), 1, d.limits());
  const auto& ca = a.runner->state().channels;
  const auto& cb = b.runner->state().channels;
  ASSERT_EQ(ca.size(), cb.size());
  for (size_t i = 0; i < ca.size(); ++i) {
    EXPECT_EQ(std::memcmp(&ca[i].mean, &cb[i].mean, sizeof(double)), 0) << i;
    EXPECT_EQ(std::memcmp(&ca[i].m2, &cb[i].m2, sizeof(double)), 0) << i;
  }
  EXPECT_GT(ca[0].mean, 0.0);
}

TEST(Mtl, LibrariesCannotEscapeOrBlock) {
  Dir d("tally_mtl_escape");
  d.write("outside/x.mtl", kMtl);
  d.write("assets/m/up.obj", std::string("mtllib ../../outside/x.mtl\n") + (kObj + 15));
  const std::string up = error_of(obj_scene("m/up.obj"), d.limits());
  EXPECT_EQ(up.rfind("/scene/shapes/0/obj:", 0), 0u) << up;
  EXPECT_NE(up.find("must not contain \"..\""), std::string::npos) << up;
  d.write("assets/m/abs.obj", "mtllib " + (d.root / "outside" / "x.mtl").string() + "\n" + (kObj + 15));
  EXPECT_EQ(error_of(obj_scene("m/abs.obj"), d.limits()).rfind("/scene/shapes/0/obj:", 0), 0u);
  // A FIFO named as the library, inside the asset directory: refused, never blocks.
  ASSERT_EQ(::mkfifo((d.root / "assets" / "m" / "pipe.mtl").c_str(), 0600), 0);
  d.write("assets/m/fifo.obj", std::string("mtllib pipe.mtl\n") + (kObj + 15));
  auto f = std::async(std::launch::async, [&] { return error_of(obj_scene("m/fifo.obj"), d.limits()); });
  if (f.wait_for(std::chrono::seconds(10)) == std::future_status::timeout) {
    const int fd = ::open((d.root / "assets" / "m" / "pipe.mtl").c_str(), O_WRONLY | O_NONBLOCK);
    if (fd >= 0) ::close(fd);
    f.get();
    FAIL() << "blocked on a FIFO";
  }
  const std::string fifo = f.get();
  EXPECT_EQ(fifo.rfind("/scene/shapes/0/obj:", 0), 0u) << fifo;
  EXPECT_NE(fifo.find("not a regular file"), std::string::npos) << fifo;
}

TEST(Mtl, MissingMaterialsAndTexturesAreNamed) {
  Dir d("tally_mtl_missing");
  d.write("assets/m/none.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
  EXPECT_NE(error_of(obj_scene("m/none.obj"), d.limits()).find("no .mtl material"), std::string::npos);
  d.write("assets/m/tex.obj", std::string("mtllib tex.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl t\nf 1 2 3\n"));
  d.write("assets/m/tex.mtl", "newmtl t\nKd 1 1 1\nmap_Kd wood.png\n");
  EXPECT_NE(error_of(obj_scene("m/tex.obj"), d.limits()).find("map_Kd"), std::string::npos);
}

}  // namespace
}  // namespace tally
