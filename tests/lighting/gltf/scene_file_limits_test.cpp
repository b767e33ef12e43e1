// Bounded readers for the files a scene names (issue 27 N1, N2, N4, N14; docs/security.md,
// "Scene files"): each hostile shape is built here, small, and refused by the limit it
// crosses with a message naming the limit and the number, before what it counts is
// allocated; primitives and OBJ material groups keep only the vertices they use.
#include <gtest/gtest.h>

#include <chrono>
#include <cstring>
#include <filesystem>
#include <map>
#include <fstream>
#include <string>

#include "common/lighting/obj_scene.hpp"
#include "common/lighting/scene_json.hpp"
#include "lighting/gltf/gltf_writer.hpp"
#include "lighting/lighting_test_support.hpp"

namespace tally {
namespace {

using json = nlohmann::json;
using test::GltfWriter;
using Dir = test::AssetSandbox;
constexpr auto* parse = &test::parse_scene_json;
constexpr auto* error_of = &test::scene_error;

json gltf_shape(const std::string& file) { return {{"shapes", json::array({{{"type", "gltf"}, {"file", file}}})}}; }
json obj_shape(const std::string& file) {
  return {{"shapes", json::array({{{"type", "mesh"}, {"obj", file}, {"material", "m"}}})},
          {"materials", {{"m", {{"type", "diffuse"}, {"albedo", {0.5, 0.5, 0.5}}}}}}};
}

bool contains(const std::string& s, const std::string& part) { return s.find(part) != std::string::npos; }

// The .glb of a JSON text (no binary chunk).
std::string glb_of(std::string js) {
  while (js.size() % 4 != 0) js.push_back(' ');
  std::string out;
  auto u32 = [&](uint32_t x) { out.append(reinterpret_cast<const char*>(&x), 4); };
  u32(0x46546C67u);
  u32(2);
  u32(static_cast<uint32_t>(12 + 8 + js.size()));
  u32(static_cast<uint32_t>(js.size()));
  u32(0x4E4F534Au);
  return out + js;
}

// N1: 15,000 nested arrays in "extras" overflowed tinygltf's recursive parser (SIGSEGV).
TEST(SceneFileLimits, DeeplyNestedGltfJsonIsRefusedByItsDepth) {
  Dir d("tally_limits_depth");
  const std::string deep =
      R"({"asset":{"version":"2.0"},"extras":)" + std::string(15000, '[') + std::string(15000, ']') + "}";
  d.write("assets/deep.gltf", deep);
  d.write("assets/deep.glb", glb_of(deep));
  for (const char* f : {"deep.gltf", "deep.glb"}) {
    const std::string err = error_of(gltf_shape(f), d.limits());
    EXPECT_EQ(err.rfind("/scene/shapes/0/file:", 0), 0u) << err;
    EXPECT_TRUE(contains(err, std::string("\"") + f + "\"")) << err;
    EXPECT_TRUE(contains(err, "deeper than 64 levels (max_file_json_depth)")) << err;
  }
  // The limit is the file's depth: 3 levels pass a limit of 3 and fail one of 2.
  d.write("assets/three.gltf", R"({"asset":{"version":"2.0"},"extras":[[1]]})");
  JobLimits l = d.limits();
  l.max_file_json_depth = 3;
  EXPECT_EQ(error_of(gltf_shape("three.gltf"), l), "");
  l.max_file_json_depth = 2;
  EXPECT_TRUE(contains(error_of(gltf_shape("three.gltf"), l), "deeper than 2 levels")) << error_of(gltf_shape("three.gltf"), l);
}

// fuzz_scene_files: a .glb whose BIN chunk declares 108 bytes with 100 left in the file
// was read past the end by tinygltf (ASan: heap-buffer-overflow). It is refused first.
TEST(SceneFileLimits, GlbChunkRunningPastTheFileIsRefused) {
  Dir d("tally_limits_glb_chunk");
  const std::string js =
      R"({"asset":{"version":"2.0"},"buffers":[{"byteLength":108}],"bufferViews":[{"buffer":0,"byteLength":96}],)"
      R"("accessors":[{"bufferView":0,"componentType":5126,"count":8,"type":"VEC3"}],)"
      R"("meshes":[{"primitives":[{"attributes":{"POSITION":0}}]}],"nodes":[{"mesh":0}],"scenes":[{"nodes":[0]}],"scene":0})";
  const auto with_bin = [&](uint32_t declared, size_t held) {
    std::string glb = glb_of(js);
    auto u32 = [&](uint32_t x) { glb.append(reinterpret_cast<const char*>(&x), 4); };
    u32(declared);
    u32(0x004E4942u);  // "BIN\0"
    glb.append(held, '\0');
    const uint32_t total = static_cast<uint32_t>(glb.size());
    std::memcpy(glb.data() + 8, &total, 4);
    return glb;
  };
  d.write("assets/short.glb", with_bin(108, 100));
  const std::string err = error_of(gltf_shape("short.glb"), d.limits());
  EXPECT_TRUE(contains(err, "a chunk of the .glb runs past the end of the file")) << err;
  d.write("assets/cut.glb", glb_of(js) + std::string(5, '\0'));  // a chunk header cut off
  EXPECT_TRUE(contains(error_of(gltf_shape("cut.glb"), d.limits()), "runs past the end")) << error_of(gltf_shape("cut.glb"), d.limits());
  // The same file with its 108 bytes whole is read (all eight vertices at the origin).
  d.write("assets/whole.glb", with_bin(108, 108));
  EXPECT_FALSE(contains(error_of(gltf_shape("whole.glb"), d.limits()), "runs past the end"))
      << error_of(gltf_shape("whole.glb"), d.limits());
}

// N2: 4.5 MB of empty nodes took 1.1 GB once tinygltf built them; they are counted first.
TEST(SceneFileLimits, GltfNodesAreCountedBeforeTheyAreBuilt) {
  Dir d("tally_limits_nodes");
  auto nodes = [](size_t n) {
    std::string s = R"({"asset":{"version":"2.0"},"nodes":[)";
    for (size_t i = 0; i < n; ++i) s += i == 0 ? "{}" : ",{}";
    return s + "]}";
  };
  JobLimits l = d.limits();
  l.max_gltf_nodes = 1000;
  d.write("assets/n1000.gltf", nodes(1000));
  d.write("assets/n1001.gltf", nodes(1001));
  EXPECT_EQ(error_of(gltf_shape("n1000.gltf"), l), "");
  EXPECT_TRUE(contains(error_of(gltf_shape("n1001.gltf"), l), "/nodes has 1001 entries, more than the limit of 1000 (max_gltf_nodes)"))
      << error_of(gltf_shape("n1001.gltf"), l);
  // The probe's file at the default limit: refused from the count, in well under a second.
  d.write("assets/many.gltf", nodes(1'500'000));
  const auto t0 = std::chrono::steady_clock::now();
  const std::string err = error_of(gltf_shape("many.gltf"), d.limits());
  const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  EXPECT_TRUE(contains(err, "/nodes has 1500000 entries, more than the limit of 65536 (max_gltf_nodes)")) << err;
  EXPECT_LT(s, 5.0);
}

// One POSITION accessor of `n` vertices (vertex i at (i, 2i, 3i)) shared by `prims`
// one-triangle primitives; primitive p uses vertices 3p * 1000 + {0, 1, 2}.
GltfWriter shared_accessor(size_t n, size_t prims) {
  GltfWriter w;
  std::vector<float> pos(3 * n);
  for (size_t i = 0; i < n; ++i) {
    pos[3 * i] = static_cast<float>(i);
    pos[3 * i + 1] = static_cast<float>(2 * i);
    pos[3 * i + 2] = static_cast<float>(3 * i);
  }
  const int acc = w.floats(pos, 3);
  json primitives = json::array();
  for (size_t p = 0; p < prims; ++p) {
    const uint32_t b = static_cast<uint32_t>(3 * p * 1000);
    primitives.push_back({{"attributes", {{"POSITION", acc}}}, {"indices", w.indices({b + 2, b, b + 1})}});
  }
  w.doc["meshes"].push_back({{"primitives", primitives}});
  w.node({{"mesh", 0}});
  return w;
}

// N2: every primitive kept a copy of the whole shared accessor (~110 MB each at 3.1 M vertices).
TEST(SceneFileLimits, PrimitivesSharingAnAccessorKeepOnlyTheirVertices) {
  Dir d("tally_limits_shared");
  const GltfWriter w = shared_accessor(100'000, 8);
  d.write("assets/shared.glb", w.glb());
  const Scene s = parse(gltf_shape("shared.glb"), d.limits());
  ASSERT_EQ(s.shapes.size(), 8u);
  for (size_t p = 0; p < 8; ++p) {
    const Shape& sh = s.shapes[p];
    ASSERT_EQ(sh.vertices.size(), 3u) << "primitive " << p;
    ASSERT_EQ(sh.triangles.size(), 1u);
    // The triangle's corners are the accessor's vertices b + 2, b, b + 1.
    const double b = 3.0 * static_cast<double>(p) * 1000.0;
    const std::array<double, 3> want{b + 2, b, b + 1};
    for (size_t k = 0; k < 3; ++k) {
      const Vec3 v = sh.vertices[sh.triangles[0][k]];
      EXPECT_EQ(v.x, want[k]);
      EXPECT_EQ(v.y, 2 * want[k]);
      EXPECT_EQ(v.z, 3 * want[k]);
    }
  }
  EXPECT_EQ(s.vertex_count(), 24u);
  // max_vertices counts what is kept: 24 fit, 23 do not (the 8th primitive crosses it).
  JobLimits l = d.limits();
  l.max_vertices = 24;
  EXPECT_EQ(error_of(gltf_shape("shared.glb"), l), "");
  l.max_vertices = 23;
  const std::string err = error_of(gltf_shape("shared.glb"), l);
  EXPECT_TRUE(contains(err, "/meshes/0/primitives/7: 3 more vertices, more than the limit of 23 in the scene (max_vertices)"))
      << err;
  // Primitives are shapes: declared counts over max_shapes are refused from the JSON.
  l = d.limits();
  l.max_shapes = 7;
  EXPECT_TRUE(contains(error_of(gltf_shape("shared.glb"), l), "/meshes declare 8 primitives, more than the limit of 7 (max_shapes)"))
      << error_of(gltf_shape("shared.glb"), l);
}

// N2, OBJ: each of 64 material groups kept a copy of all 2 M vertices (4.6 GB).
TEST(ObjLimits, MaterialGroupsKeepOnlyTheirVertices) {
  Dir d("tally_limits_obj_groups");
  std::string obj = "mtllib g.mtl\n", mtl;
  for (int i = 0; i < 1000; ++i) obj += "v " + std::to_string(i) + " " + std::to_string(i % 7) + " 0\n";
  for (int g = 0; g < 4; ++g) {
    mtl += "newmtl m" + std::to_string(g) + "\nKd 0.5 0.5 0.5\n";
    obj += "usemtl m" + std::to_string(g) + "\n";
    const int b = 1 + 100 * g;
    obj += "f " + std::to_string(b) + " " + std::to_string(b + 1) + " " + std::to_string(b + 2) + "\n";
    obj += "f " + std::to_string(b) + " " + std::to_string(b + 2) + " " + std::to_string(b + 3) + "\n";
  }
  d.write("assets/g.obj", obj);
  d.write("assets/g.mtl", mtl);
  const json scene = {{"shapes", json::array({{{"type", "mesh"}, {"obj", "g.obj"}}})}};
  const Scene s = parse(scene, d.limits());
  ASSERT_EQ(s.shapes.size(), 4u);
  for (size_t g = 0; g < 4; ++g) {
    ASSERT_EQ(s.shapes[g].vertices.size(), 4u) << "group " << g;
    // Face 1 of group g: OBJ vertices b, b+1, b+2 (1-based) = x of b-1, b, b+1.
    const double x0 = 100.0 * static_cast<double>(g);
    EXPECT_EQ(s.shapes[g].vertices[s.shapes[g].triangles[0][0]].x, x0);
    EXPECT_EQ(s.shapes[g].vertices[s.shapes[g].triangles[0][1]].x, x0 + 1);
    EXPECT_EQ(s.shapes[g].vertices[s.shapes[g].triangles[0][2]].x, x0 + 2);
  }
  JobLimits l = d.limits();
  l.max_vertices = 15;
  EXPECT_TRUE(contains(error_of(scene, l), "more than 15 vertices in the file (max_vertices)")) << error_of(scene, l);
  l.max_vertices = 1000;
  EXPECT_EQ(error_of(scene, l), "");
  l.max_shapes = 3;
  EXPECT_TRUE(contains(error_of(scene, l), "more than 3 materials used, each a shape (max_shapes)")) << error_of(scene, l);
}

// N4: one polygon of 100,000 corners took 37.6 s to triangulate; corners are bounded.
TEST(ObjLimits, PolygonCornersAreBounded) {
  Dir d("tally_limits_polygon");
  auto polygon = [](int n) {
    std::string s;
    for (int i = 0; i < n; ++i) {
      const double a = 2 * kPi * i / n;
      s += "v " + std::to_string(std::cos(a)) + " " + std::to_string(std::sin(a)) + " 0\n";
    }
    s += "f";
    for (int i = 1; i <= n; ++i) s += " " + std::to_string(i);
    return s + "\n";
  };
  d.write("assets/ok.obj", polygon(256));
  d.write("assets/big.obj", polygon(100'000));
  EXPECT_EQ(parse(obj_shape("ok.obj"), d.limits()).triangle_count(), 254u);
  const auto t0 = std::chrono::steady_clock::now();
  const std::string err = error_of(obj_shape("big.obj"), d.limits());
  const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  EXPECT_TRUE(contains(err, "OBJ \"big.obj\" line 100001: a face of 100000 corners, more than the limit of 256 (max_polygon_vertices)"))
      << err;
  EXPECT_LT(s, 5.0);
}

// .mtl libraries were read unchecked: each `newmtl` line, however short, becomes a
// ~1.9 KB tinyobjloader material (a 1 GB library of "newmtl a" lines, ~200 GB), and a
// library named N times by `mtllib` was read and parsed N times (one line naming a 1 MB
// library 10,000 times: a 10 GB text). Now each library is read once, and the
// libraries' materials (4096, as a scene holds) and lines (2^18) are counted first.
TEST(ObjLimits, MtlLibrariesAreReadOnceAndTheirMaterialsAndLinesAreBounded) {
  Dir d("tally_limits_mtl");
  auto library = [](int materials, int extra_lines = 0) {
    std::string s;
    for (int i = 0; i < materials; ++i) s += "newmtl m" + std::to_string(i) + "\nKd 0.5 0.5 0.5\n";
    for (int i = 0; i < extra_lines; ++i) s += "x" + std::to_string(i) + " 1\n";  // unknown keywords
    return s;
  };
  const std::string tri = "v 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl m0\nf 1 2 3\n";
  std::map<std::string, std::string> files = {
      {"twice.obj", "mtllib ok.mtl ok.mtl\nmtllib ok.mtl\n" + tri}, {"ok.mtl", library(4096)},
      {"many.obj", "mtllib many.mtl\n" + tri},                      {"many.mtl", library(4097)},
      {"split.obj", "mtllib a.mtl b.mtl\n" + tri},                 {"a.mtl", library(2048)},
      {"b.mtl", library(2049)},                                     {"long.obj", "mtllib long.mtl\n" + tri},
      {"long.mtl", library(1, (1 << 18) - 2)},                      {"longer.obj", "mtllib longer.mtl\n" + tri},
      {"longer.mtl", library(1, (1 << 18) - 1)}};
  std::map<std::string, int> reads;
  const AssetReader read = [&](const std::string& name, const std::string&) {
    ++reads[name];
    return files.at(name);
  };
  auto load = [&](const std::string& obj) -> std::string {
    Scene scene;
    try {
      const std::vector<Shape> shapes = load_obj(obj, "/scene/shapes/0/obj", read, d.limits(), std::nullopt, scene);
      EXPECT_EQ(shapes.size(), 1u) << obj;
    } catch (const SpecError& e) {
      return e.what();
    }
    return "";
  };
  EXPECT_EQ(load("twice.obj"), "");
  EXPECT_EQ(reads["ok.mtl"], 1) << "named three times, read once";
  EXPECT_EQ(load("many.obj"),
            "/scene/shapes/0/obj: .mtl \"many.mtl\" line 8193: more than 4096 materials in the OBJ's .mtl libraries");
  // The count is over all the OBJ's libraries together.
  EXPECT_EQ(load("split.obj"),
            "/scene/shapes/0/obj: .mtl \"b.mtl\" line 4097: more than 4096 materials in the OBJ's .mtl libraries");
  EXPECT_EQ(load("long.obj"), "");  // newmtl, Kd and 2^18 - 2 more: 2^18 lines
  EXPECT_EQ(load("longer.obj"),
            "/scene/shapes/0/obj: .mtl \"longer.mtl\" line 262145: more than 262144 lines in the OBJ's .mtl libraries");
}

// N14, OBJ: "nan" and an index past 2^64 were accepted.
TEST(ObjLimits, NonFiniteNumbersAndBadIndicesNameTheLine) {
  Dir d("tally_limits_obj_numbers");
  const std::string tri = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"v nan 0 0\n" + tri + "f 1 2 3\n", "line 1: \"nan\" is not a finite number within 1e12"},
      {tri + "v 1e400 0 0\nf 1 2 3\n", "line 4: \"1e400\" is not a finite number within 1e12"},
      {tri + "vt inf 0\nf 1 2 3\n", "line 4: \"inf\" is not a finite number within 1e12"},
      {tri + "f 1 2 99999999999999999999\n", "line 4: vertex index \"99999999999999999999\" names none of the 3 given so far"},
      {tri + "f 1 2 4\n", "line 4: vertex index \"4\" names none of the 3 given so far"},
      {tri + "f 1 2 0\n", "line 4: vertex index \"0\" names none"},
      {tri + "f 1 2 -4\n", "line 4: vertex index \"-4\" names none"},
      {tri + "f 1/1 2/1 3/1\n", "line 4: texture coordinate index \"1\" names none of the 0 given so far"},
      {tri + "f 1 2\n", "line 4: a face needs at least 3 corners"},
      {tri + "v 1 x 0\nf 1 2 3\n", "line 4: \"x\" is not a finite number"},
  };
  for (size_t i = 0; i < cases.size(); ++i) {
    d.write("assets/bad.obj", cases[i].first);
    const std::string err = error_of(obj_shape("bad.obj"), d.limits());
    EXPECT_EQ(err.rfind("/scene/shapes/0/obj: OBJ \"bad.obj\" ", 0), 0u) << i << ": " << err;
    EXPECT_TRUE(contains(err, cases[i].second)) << i << ": " << err;
  }
  // Relative (negative) indices within range, and v/vt/vn forms, are fine.
  d.write("assets/good.obj", tri + "vt 0 0\nvn 0 0 1\nf -3/1/1 -2/1/1 -1//1\n");
  EXPECT_EQ(error_of(obj_shape("good.obj"), d.limits()), "");
}

}  // namespace
}  // namespace tally
