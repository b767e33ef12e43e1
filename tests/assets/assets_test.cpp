// Assets over HTTP against the real tally-server: PUT/HEAD /v1/assets/sha256:<hex>,
// scenes naming stored assets, restart, retention, quota and tenancy, and the CLI's
// upload of what the server lacks.
#include <arpa/inet.h>
#include <fmt/format.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/time.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <limits>
#include <sstream>
#include <thread>

#include "common/image/image_io.hpp"
#include "lighting/gltf/gltf_writer.hpp"
#include "support/loopback_socket.hpp"
#include "server/auth/token.hpp"
#include "server_process.hpp"

namespace tally::e2e {
namespace {

namespace fs = std::filesystem;
using test::connect_loopback;
using test::send_all;
using nlohmann::json;

// The SHA-256 of the bytes in lowercase hex (the one-shot digest of server/auth; the
// asset store hashes its streamed parts with its own code).
std::string sha256_hex(std::string_view bytes) { return token_sha256_hex(bytes); }

std::string asset_url(const std::string& hex) { return "/v1/assets/sha256:" + hex; }

size_t files_in(const fs::path& dir) {
  std::error_code ec;
  size_t n = 0;
  for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) ++n;
  return n;
}

// A lower bound on tile_red_sum of the lit scenes below: about 100 floor pixels under a
// 1x1 lamp of radiance 1 to 4, 1.5 above, each reflect 0.8/pi of an irradiance of 0.1 to
// 1.8 (measured sums, fixed seeds: 21.4 OBJ lamp, 5.3 .glb lamp, 63.9 environment map).
// Were the asset ignored, the image would be black: exactly 0.
constexpr double kMinTileLight = 1.0;

std::string problem_of(const ClientResponse& r) {
  const json p = json::parse(r.body, nullptr, false);
  return p.is_object() && p.contains("detail") ? p["detail"].get<std::string>() : r.body;
}

// A small OBJ: a 1x1 emitting square at z = 1.5 facing down, in `rows` strips.
std::string lamp_obj(int rows = 1) {
  std::ostringstream o;
  for (int i = 0; i <= rows; ++i) {
    const double y = -0.5 + static_cast<double>(i) / rows;
    o << "v -0.5 " << y << " 1.5\nv 0.5 " << y << " 1.5\n";
  }
  for (int i = 0; i < rows; ++i) {
    const int a = 2 * i + 1;
    o << "f " << a << " " << a + 2 << " " << a + 3 << "\nf " << a << " " << a + 3 << " " << a + 1 << "\n";
  }
  return o.str();
}

// A small lighting image job whose lamp is the mesh `obj` names.
json obj_image_spec(const std::string& obj) {
  return json{
      {"kind", "lighting"},
      {"seed", 7},
      {"scene",
       {{"camera",
         {{"position", {0, -3, 0.75}},
          {"look_at", {0, 0, 0.75}},
          {"up", {0, 0, 1}},
          {"fov_deg", 60},
          {"resolution", {16, 12}}}},
        {"materials",
         {{"floor", {{"type", "diffuse"}, {"albedo", {0.8, 0.8, 0.8}}}},
          {"lamp", {{"type", "emissive"}, {"radiance", {4, 4, 4}}}}}},
        {"shapes",
         json::array({{{"type", "quad"}, {"corner", {-2, -2, 0}}, {"edge_u", {4, 0, 0}}, {"edge_v", {0, 4, 0}},
                       {"material", "floor"}},
                      {{"type", "mesh"}, {"obj", obj}, {"material", "lamp"}}})}}},
      {"query", {{"type", "image"}, {"max_depth", 2}}},
      {"estimators", {"mis"}},
      {"stop", {{"max_samples", 16}}},  // per pixel
  };
}

ClientResponse put(HttpClient& c, const std::string& hex, const std::string& body) {
  return c.request("PUT", asset_url(hex), body, {{"Content-Type", "application/octet-stream"}});
}

TEST(Assets, UploadHeadAndTheSameAssetTwiceIsStoredOnce) {
  TempDir tmp;
  ServerProcess server(tmp.path / "data");
  HttpClient c = server.client();
  const std::string body = lamp_obj(3);
  const std::string hex = sha256_hex(body);
  EXPECT_EQ(c.request("HEAD", asset_url(hex)).status, 404);
  const ClientResponse first = put(c, hex, body);
  ASSERT_EQ(first.status, 201) << first.body;
  EXPECT_EQ(json::parse(first.body).at("bytes"), body.size());
  EXPECT_EQ(first.header("Location"), asset_url(hex));
  const fs::path blob = tmp.path / "data" / "assets" / "sha256" / hex;
  std::ifstream in(blob, std::ios::binary);
  EXPECT_EQ(std::string(std::istreambuf_iterator<char>(in), {}), body);
  struct stat st1 {};
  ASSERT_EQ(::stat(blob.c_str(), &st1), 0);
  const ClientResponse second = put(c, hex, body);
  EXPECT_EQ(second.status, 200) << second.body;
  struct stat st2 {};
  ASSERT_EQ(::stat(blob.c_str(), &st2), 0);
  EXPECT_EQ(st1.st_ino, st2.st_ino);  // not rewritten (a new file would be renamed over it)
  EXPECT_EQ(files_in(blob.parent_path()), 1u);
  EXPECT_EQ(files_in(tmp.path / "data" / "assets" / "tmp"), 0u);
  const ClientResponse head = c.request("HEAD", asset_url(hex));
  EXPECT_EQ(head.status, 200);
  EXPECT_EQ(head.header("X-Asset-Bytes"), std::to_string(body.size()));
  EXPECT_TRUE(head.body.empty());
  // Malformed names: 400.
  EXPECT_EQ(put(c, "abc", body).status, 400);
  EXPECT_EQ(c.request("PUT", "/v1/assets/md5:" + hex, body).status, 400);
  EXPECT_EQ(put(c, std::string(64, 'G'), body).status, 400);
  EXPECT_EQ(c.request("HEAD", "/v1/assets/" + hex).status, 400);
}

TEST(Assets, HashMismatchIs422AndNothingIsKept) {
  TempDir tmp;
  ServerProcess server(tmp.path / "data");
  HttpClient c = server.client();
  const std::string body = lamp_obj(2);
  const std::string wrong = sha256_hex(body + " ");
  const ClientResponse r = put(c, wrong, body);
  EXPECT_EQ(r.status, 422) << r.body;
  EXPECT_NE(problem_of(r).find(sha256_hex(body)), std::string::npos) << r.body;  // names the body's real hash
  EXPECT_EQ(files_in(tmp.path / "data" / "assets" / "sha256"), 0u);
  EXPECT_EQ(files_in(tmp.path / "data" / "assets" / "tmp"), 0u);
  EXPECT_EQ(c.request("HEAD", asset_url(wrong)).status, 404);
}

TEST(Assets, OverSizeIs413AndNothingIsKeptDeclaredOrChunked) {
  TempDir tmp;
  ServerProcess server(tmp.path / "data", {"--max-asset-bytes", "1000"});
  HttpClient c = server.client();
  const std::string big(2000, 'x');
  const std::string hex = sha256_hex(big);
  const ClientResponse declared = put(c, hex, big);  // Content-Length over the limit: refused before the body
  EXPECT_EQ(declared.status, 413) << declared.body;
  EXPECT_NE(problem_of(declared).find("1000"), std::string::npos);
  // Chunked (no Content-Length): refused when the streamed bytes pass the limit.
  std::string raw = "PUT " + asset_url(hex) + " HTTP/1.1\r\nHost: 127.0.0.1\r\nTransfer-Encoding: chunked\r\n\r\n";
  for (int i = 0; i < 4; ++i) raw += "1f4\r\n" + std::string(500, 'x') + "\r\n";
  raw += "0\r\n\r\n";
  const std::string answer = c.raw_exchange(raw);
  EXPECT_EQ(answer.substr(0, 12), "HTTP/1.1 413") << answer;
  EXPECT_EQ(files_in(tmp.path / "data" / "assets" / "sha256"), 0u);
  EXPECT_EQ(files_in(tmp.path / "data" / "assets" / "tmp"), 0u);
  // Exactly at the limit is fine.
  const std::string ok(1000, 'y');
  EXPECT_EQ(put(c, sha256_hex(ok), ok).status, 201);
}

TEST(Assets, InterruptedUploadKeepsNothing) {
  TempDir tmp;
  ServerProcess server(tmp.path / "data");
  const std::string body(4 << 20, 'z');
  const std::string hex = sha256_hex(body);
  const int fd = connect_loopback(server.port(), 30);
  ASSERT_GE(fd, 0);
  const std::string head = "PUT " + asset_url(hex) + " HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: " +
                           std::to_string(body.size()) + "\r\n\r\n";
  ASSERT_TRUE(send_all(fd, head + body.substr(0, body.size() / 2)));  // half the body
  // The body streams to a temp file (not into memory): it appears while the upload is open.
  const fs::path tmpdir = tmp.path / "data" / "assets" / "tmp";
  const auto t0 = std::chrono::steady_clock::now();
  while (files_in(tmpdir) == 0 && std::chrono::steady_clock::now() - t0 < std::chrono::seconds(10)) {
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  EXPECT_EQ(files_in(tmpdir), 1u);
  ::close(fd);  // the client goes away mid-body
  const auto t1 = std::chrono::steady_clock::now();
  while (files_in(tmpdir) > 0 && std::chrono::steady_clock::now() - t1 < std::chrono::seconds(10)) {
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  EXPECT_EQ(files_in(tmpdir), 0u);
  EXPECT_EQ(files_in(tmp.path / "data" / "assets" / "sha256"), 0u);
  HttpClient c = server.client();
  EXPECT_EQ(c.request("HEAD", asset_url(hex)).status, 404);
  // The same asset sent whole afterwards is stored.
  EXPECT_EQ(c.send_file("PUT", asset_url(hex), [&] {
    const fs::path f = tmp.path / "big.bin";
    std::ofstream(f, std::ios::binary) << body;
    return f.string();
  }()).status, 201);
  EXPECT_EQ(c.request("HEAD", asset_url(hex)).status, 200);
}

TEST(Assets, SceneNamingAMissingAssetIs422NamingIt) {
  TempDir tmp;
  ServerProcess server(tmp.path / "data");
  HttpClient c = server.client();
  const std::string hex = sha256_hex("not uploaded");
  for (const char* route : {"/v1/jobs", "/v1/jobs/validate"}) {
    const ClientResponse r =
        c.request("POST", route, obj_image_spec("sha256:" + hex).dump(), {{"Content-Type", "application/json"}});
    EXPECT_EQ(r.status, 422) << route << r.body;
    const json p = json::parse(r.body);
    EXPECT_EQ(p.at("pointer"), "/scene/shapes/1/obj");
    EXPECT_NE(p.at("detail").get<std::string>().find("sha256:" + hex), std::string::npos) << r.body;
  }
  // A malformed reference is named too.
  const ClientResponse bad =
      c.request("POST", "/v1/jobs", obj_image_spec("sha256:1234").dump(), {{"Content-Type", "application/json"}});
  EXPECT_EQ(bad.status, 422);
  EXPECT_EQ(json::parse(bad.body).at("pointer"), "/scene/shapes/1/obj");
}

// The light a finished image job's tile 0 holds: the sum over its pixels of the mean's
// red channel. Every scene here is lit only by the asset (a lamp mesh or an environment
// map): were the asset ignored, the image would be black and this exactly 0.
double tile_red_sum(HttpClient& c, const std::string& id) {
  const ClientResponse t = c.request("GET", "/v1/jobs/" + id + "/tiles/0");
  if (t.status != 200) return -1;
  const json mean = json::parse(t.body).at("mean");
  double sum = 0;
  for (size_t i = 0; i < mean.size(); i += 3) sum += mean[i].get<double>();
  return sum;
}

// A server whose --asset-dir holds `name` with `bytes`, the same bytes also uploaded
// (PUT) as an asset: the scene file can be named both ways.
struct SameFileTwice {
  static fs::path write(const TempDir& tmp, const std::string& name, const std::string& bytes) {
    fs::create_directories(tmp.path / "dir");
    std::ofstream(tmp.path / "dir" / name, std::ios::binary) << bytes;
    return tmp.path / "data";
  }
  SameFileTwice(const std::string& name, const std::string& bytes)
      : hex(sha256_hex(bytes)),
        server(write(tmp, name, bytes), {"--asset-dir", (tmp.path / "dir").string()}),
        c(server.client()) {
    EXPECT_EQ(put(c, hex, bytes).status, 201);
  }
  // Both jobs (`spec_of(name)`, `spec_of("sha256:<hex>")`) end with the same bits and
  // the same pixels of tile 0.
  template <class SpecOf>
  void expect_by_path_equals_by_hash(const std::string& name, SpecOf spec_of) {
    const std::string by_path = submit(c, spec_of(name));
    const std::string by_hash = submit(c, spec_of("sha256:" + hex));
    const json a = wait_state(c, by_path, "succeeded");
    const json b = wait_state(c, by_hash, "succeeded");
    EXPECT_EQ(a.at("bits"), b.at("bits"));
    const ClientResponse ta = c.request("GET", "/v1/jobs/" + by_path + "/tiles/0");
    const ClientResponse tb = c.request("GET", "/v1/jobs/" + by_hash + "/tiles/0");
    ASSERT_EQ(ta.status, 200);
    EXPECT_EQ(ta.body, tb.body);
    EXPECT_FALSE(ta.body.empty());
    // The asset is what lights the scene: bit-identical black images would pass above.
    EXPECT_GT(tile_red_sum(c, by_path), kMinTileLight) << ta.body;
  }
  TempDir tmp;
  std::string hex;
  ServerProcess server;
  HttpClient c;
};

TEST(Assets, UploadedObjRendersBitIdenticalToTheSameFileFromAssetDir) {
  SameFileTwice("lamp.obj", lamp_obj(4)).expect_by_path_equals_by_hash("lamp.obj", obj_image_spec);
}

// The lamp as a self-contained glTF (.glb): a 1x1 emissive square at z = 1.5 facing down.
std::string lamp_glb() {
  test::GltfWriter w;
  const int lamp = w.material({{"emissiveFactor", {1.0, 0.9, 0.8}},
                               {"pbrMetallicRoughness", {{"baseColorFactor", {0, 0, 0, 1}}, {"metallicFactor", 0.0}}}});
  w.node({{"mesh", w.mesh({-0.5f, -0.5f, 1.5f, -0.5f, 0.5f, 1.5f, 0.5f, 0.5f, 1.5f, 0.5f, -0.5f, 1.5f}, {0, 1, 2, 0, 2, 3}, lamp)}});
  return w.glb();
}

json glb_image_spec(const std::string& file) {
  json spec = obj_image_spec("unused.obj");
  spec["scene"]["shapes"][1] = {{"type", "gltf"}, {"file", file}};
  spec["scene"]["materials"].erase("lamp");
  return spec;
}

// The lamp twice more as scene files that name another stored file inside them: a
// .gltf whose buffer is "sha256:<bin>", and an OBJ whose material library is
// "mtllib sha256:<mtl>" (an emissive .mtl material).
struct NestedLamps {
  NestedLamps() {
    // The lamp at height z as a .gltf whose one buffer is the stored .bin named `prefix` + its hash.
    auto lamp_gltf = [](float z, const std::string& prefix, std::string& bin_out) {
      test::GltfWriter w;
      const int lamp = w.material({{"emissiveFactor", {1.0, 0.9, 0.8}},
                                   {"pbrMetallicRoughness", {{"baseColorFactor", {0, 0, 0, 1}}, {"metallicFactor", 0.0}}}});
      w.node({{"mesh", w.mesh({-0.5f, -0.5f, z, -0.5f, 0.5f, z, 0.5f, 0.5f, z, 0.5f, -0.5f, z}, {0, 1, 2, 0, 2, 3}, lamp)}});
      bin_out = w.bin;
      json doc = w.doc;
      doc["buffers"] = json::array({{{"byteLength", bin_out.size()}, {"uri", prefix + sha256_hex(bin_out)}}});
      return doc.dump();
    };
    gltf = lamp_gltf(1.5f, "sha256:", bin);
    obj = "mtllib sha256:" + sha256_hex(mtl) + "\nusemtl glow\n" + lamp_obj(1);
    // The lamp 0.1 lower, its own buffer named with a percent-encoded colon, which the
    // glTF loader decodes ("sha256%3A<hex>"; the text "sha256:<hex>" is nowhere in it).
    escaped_gltf = lamp_gltf(1.4f, "sha256%3A", escaped_bin);
  }
  json gltf_spec() const { return glb_image_spec("sha256:" + sha256_hex(gltf)); }
  json escaped_gltf_spec() const { return glb_image_spec("sha256:" + sha256_hex(escaped_gltf)); }
  json obj_spec() const {
    json spec = obj_image_spec("sha256:" + sha256_hex(obj));
    spec["scene"]["shapes"][1].erase("material");  // the OBJ's own materials
    return spec;
  }
  std::string bin, gltf, mtl = "newmtl glow\nKd 0 0 0\nKe 4 4 4\n", obj, escaped_bin, escaped_gltf;
};

// Waits (at most 20 s) until the server's log holds `text` `times` times (the log is
// appended to across restarts on the same data dir).
bool wait_for_log(const ServerProcess& server, const std::string& text, size_t times = 1) {
  auto count = [&] {
    const std::string log = server.log();
    size_t n = 0;
    for (size_t at = log.find(text); at != std::string::npos; at = log.find(text, at + 1)) ++n;
    return n;
  };
  const auto t0 = std::chrono::steady_clock::now();
  while (count() < times) {
    if (std::chrono::steady_clock::now() - t0 > std::chrono::seconds(20)) return false;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  return true;
}

TEST(Assets, UploadedGlbRendersBitIdenticalToTheSameFileFromAssetDir) {
  SameFileTwice("lamp.glb", lamp_glb()).expect_by_path_equals_by_hash("lamp.glb", glb_image_spec);
}

// An equirectangular map as EXR bytes (the image module's encoder: R, G, B come first, the
// extra channels are ignored by the map reader).
std::string env_map_exr(int w, int h, float nan_at = -1) {
  ImageSnapshot im;
  im.width = im.full_width = w;
  im.height = im.full_height = h;
  const size_t n = static_cast<size_t>(w) * static_cast<size_t>(h);
  im.rgb.resize(3 * n);
  for (size_t i = 0; i < 3 * n; ++i) im.rgb[i] = 0.1f + 0.01f * static_cast<float>(i % 17);
  im.rgb[3 * (n / 3)] = 50.0f;  // a hot texel
  if (nan_at >= 0) im.rgb[static_cast<size_t>(nan_at)] = std::numeric_limits<float>::quiet_NaN();
  im.stderr_rgb.assign(3 * n, 0.0f);
  im.samples.assign(n, 1.0f);
  return encode_exr(im, json::object());
}

json env_image_spec(const std::string& map) {
  json spec = obj_image_spec("unused");
  spec["scene"]["shapes"].erase(1);  // the floor only, lit by the map
  spec["scene"]["lights"] = json::array({{{"type", "sky"}, {"map", map}, {"intensity", 2}, {"rotation_deg", 30}}});
  return spec;
}

TEST(Assets, UploadedEnvironmentMapLightsAJobBitIdenticalToTheSameFileFromAssetDir) {
  SameFileTwice both("sky.exr", env_map_exr(32, 16));
  both.expect_by_path_equals_by_hash("sky.exr", env_image_spec);
  HttpClient& c = both.c;
  const std::string& hex = both.hex;
  // validate answers with the plan, which names the map as the reason the sky is on.
  const ClientResponse v =
      c.request("POST", "/v1/jobs/validate", env_image_spec("sha256:" + hex).dump(), {{"Content-Type", "application/json"}});
  ASSERT_EQ(v.status, 200) << v.body;
  EXPECT_NE(v.body.find("environment map (32x16"), std::string::npos) << v.body;
  // A map with a NaN texel, uploaded: 422 naming the field and the texel.
  const std::string bad = env_map_exr(32, 16, 3 * (2 * 32 + 5) + 1);
  const std::string bad_hex = sha256_hex(bad);
  ASSERT_EQ(put(c, bad_hex, bad).status, 201);
  const ClientResponse r =
      c.request("POST", "/v1/jobs", env_image_spec("sha256:" + bad_hex).dump(), {{"Content-Type", "application/json"}});
  EXPECT_EQ(r.status, 422) << r.body;
  EXPECT_EQ(json::parse(r.body).at("pointer"), "/scene/lights/0/map");
  EXPECT_NE(problem_of(r).find("texel (column 5, row 2) channel G is nan"), std::string::npos) << r.body;
}

TEST(Assets, RestartKeepsAssetsAndRetentionRemovesOnlyUnreferenced) {
  TempDir tmp;
  const std::string used = lamp_obj(1), unused = lamp_obj(2);
  const std::string hu = sha256_hex(used), hn = sha256_hex(unused);
  {
    ServerProcess server(tmp.path / "data");
    HttpClient c = server.client();
    ASSERT_EQ(put(c, hu, used).status, 201);
    ASSERT_EQ(put(c, hn, unused).status, 201);
    wait_state(c, submit(c, obj_image_spec("sha256:" + hu)), "succeeded");
    EXPECT_EQ(server.terminate(), 0);
  }
  {
    ServerProcess server(tmp.path / "data");  // default retention: 30 days
    HttpClient c = server.client();
    EXPECT_EQ(c.request("HEAD", asset_url(hu)).status, 200);
    EXPECT_EQ(c.request("HEAD", asset_url(hn)).status, 200);
    EXPECT_EQ(server.terminate(), 0);
  }
  {
    ServerProcess server(tmp.path / "data", {"--asset-retention-days", "0"});
    HttpClient c = server.client();
    EXPECT_TRUE(wait_for_log(server, "asset retention: 1 removed")) << server.log();
    EXPECT_NE(server.log().find("removed sha256:" + hn), std::string::npos) << server.log();
    EXPECT_EQ(c.request("HEAD", asset_url(hu)).status, 200);  // a job names it
    EXPECT_EQ(c.request("HEAD", asset_url(hn)).status, 404);
    EXPECT_FALSE(fs::exists(tmp.path / "data" / "assets" / "sha256" / hn));
    EXPECT_EQ(server.terminate(), 0);
  }
}

// Issue 27 N6: retention counted only the hashes in job specs. With retention 0, a
// restart removed the .bin named inside a stored job's glTF (and the .mtl named inside
// its OBJ), and the job's spec no longer compiled ("File not found"). Now what the
// named scene files name is kept too, also a glTF's name written as its loader decodes
// it ("sha256%3A<hex>", which a scan for the text "sha256:" missed); only the asset
// nothing names goes.
TEST(Assets, RetentionKeepsWhatAJobsSceneFilesNameInside) {
  TempDir tmp;
  const NestedLamps n;
  const std::string unused = lamp_obj(2), hn = sha256_hex(unused);
  const std::vector<const std::string*> named = {&n.bin, &n.gltf, &n.mtl, &n.obj, &n.escaped_bin, &n.escaped_gltf};
  {
    ServerProcess server(tmp.path / "data");
    HttpClient c = server.client();
    for (const std::string* body : named) ASSERT_EQ(put(c, sha256_hex(*body), *body).status, 201);
    ASSERT_EQ(put(c, hn, unused).status, 201);
    wait_state(c, submit(c, n.gltf_spec()), "succeeded");
    wait_state(c, submit(c, n.obj_spec()), "succeeded");
    wait_state(c, submit(c, n.escaped_gltf_spec()), "succeeded");
    EXPECT_EQ(server.terminate(), 0);
  }
  ServerProcess server(tmp.path / "data", {"--asset-retention-days", "0"});
  HttpClient c = server.client();
  // The second start's sweep summary (the first start, with the default 30 days, kept all).
  EXPECT_TRUE(wait_for_log(server, "named by jobs)", 2)) << server.log();
  EXPECT_NE(server.log().find("asset retention: 1 removed"), std::string::npos) << server.log();
  EXPECT_NE(server.log().find("removed sha256:" + hn), std::string::npos) << server.log();
  for (const std::string* body : named) {
    EXPECT_EQ(c.request("HEAD", asset_url(sha256_hex(*body))).status, 200) << *body;
  }
  EXPECT_EQ(c.request("HEAD", asset_url(hn)).status, 404);
  // The stored jobs' scenes still compile: submitted again, they run and are lit.
  for (const json& spec : {n.gltf_spec(), n.obj_spec(), n.escaped_gltf_spec()}) {
    const std::string again = submit(c, spec);
    wait_state(c, again, "succeeded");
    EXPECT_GT(tile_red_sum(c, again), kMinTileLight);
  }
}

struct Who {
  std::string name, role, token;
  uint64_t max_asset_bytes = 0;
};

TEST(Assets, SubmitRoleQuotaAndTenancy) {
  TempDir tmp;
  std::vector<Who> who = {{"ann", "user", generate_token(), 1500},
                          {"bob", "user", generate_token(), 0},
                          {"rex", "reader", generate_token(), 0},
                          {"adm", "admin", generate_token(), 0}};
  json list = json::array();
  for (const Who& w : who) {
    json e = {{"name", w.name}, {"role", w.role}, {"token_sha256", token_sha256_hex(w.token)}};
    if (w.max_asset_bytes) e["quotas"] = {{"max_asset_bytes", w.max_asset_bytes}};
    list.push_back(e);
  }
  const fs::path auth = tmp.path / "auth.json";
  std::ofstream(auth) << json{{"principals", list}}.dump();
  ServerProcess server(tmp.path / "data", {"--auth-file", auth.string()});
  HttpClient ann = server.client(ClientSecurity{who[0].token, ""});
  HttpClient bob = server.client(ClientSecurity{who[1].token, ""});
  HttpClient rex = server.client(ClientSecurity{who[2].token, ""});
  HttpClient adm = server.client(ClientSecurity{who[3].token, ""});
  HttpClient anon = server.client();
  const std::string a1(1000, 'a'), a2(1000, 'b');
  EXPECT_EQ(put(anon, sha256_hex(a1), a1).status, 401);
  EXPECT_EQ(put(rex, sha256_hex(a1), a1).status, 403);  // readers may not upload
  EXPECT_EQ(put(ann, sha256_hex(a1), a1).status, 201);
  const ClientResponse over = put(ann, sha256_hex(a2), a2);  // 1000 + 1000 > 1500
  EXPECT_EQ(over.status, 403) << over.body;
  EXPECT_NE(problem_of(over).find("quota"), std::string::npos) << over.body;
  EXPECT_EQ(files_in(tmp.path / "data" / "assets" / "sha256"), 1u);
  EXPECT_EQ(files_in(tmp.path / "data" / "assets" / "tmp"), 0u);
  EXPECT_EQ(put(ann, sha256_hex(a1), a1).status, 200);  // already hers: no charge
  // Tenancy: bob cannot learn that ann's asset exists, nor use it in a scene ...
  EXPECT_EQ(bob.request("HEAD", asset_url(sha256_hex(a1))).status, 404);
  EXPECT_EQ(adm.request("HEAD", asset_url(sha256_hex(a1))).status, 200);  // admins see every asset
  const ClientResponse use = bob.request("POST", "/v1/jobs", obj_image_spec("sha256:" + sha256_hex(a1)).dump(),
                                         {{"Content-Type", "application/json"}});
  EXPECT_EQ(use.status, 422) << use.body;
  EXPECT_NE(problem_of(use).find("not stored"), std::string::npos);
  // ... until he uploads the bytes himself: 201 for him (as if new), stored once.
  EXPECT_EQ(put(bob, sha256_hex(a1), a1).status, 201);
  EXPECT_EQ(bob.request("HEAD", asset_url(sha256_hex(a1))).status, 200);
  EXPECT_EQ(files_in(tmp.path / "data" / "assets" / "sha256"), 1u);
}

ClientResponse post_json(HttpClient& c, const std::string& route, const json& spec) {
  return c.request("POST", route, spec.dump(), {{"Content-Type", "application/json"}});
}

// Issue 27 N5: "sha256:" names inside an uploaded scene file (a glTF's buffer, an OBJ's
// mtllib) are checked as a name in the spec is: the submitter must have uploaded them.
// Another tenant's asset answers exactly as one never stored (status and body), so the
// answer tells nothing about what others uploaded; once the submitter uploads the bytes
// itself the job runs and its lamp lights the floor.
TEST(Assets, NestedAssetNamesAreTheSubmittersOwnAndNotYoursReadsAsMissing) {
  TempDir tmp;
  const Who ann{"ann", "user", generate_token()}, bob{"bob", "user", generate_token()};
  json list = json::array();
  for (const Who& w : {ann, bob}) {
    list.push_back({{"name", w.name}, {"role", w.role}, {"token_sha256", token_sha256_hex(w.token)}});
  }
  const fs::path auth = tmp.path / "auth.json";
  std::ofstream(auth) << json{{"principals", list}}.dump();
  ServerProcess server(tmp.path / "data", {"--auth-file", auth.string()});
  HttpClient a = server.client(ClientSecurity{ann.token, ""});
  HttpClient b = server.client(ClientSecurity{bob.token, ""});

  const NestedLamps n;
  ASSERT_EQ(put(a, sha256_hex(n.gltf), n.gltf).status, 201);
  ASSERT_EQ(put(a, sha256_hex(n.obj), n.obj).status, 201);
  struct Case {
    json spec;
    std::string nested_hex, nested_bytes, pointer;
  };
  const std::vector<Case> cases = {{n.gltf_spec(), sha256_hex(n.bin), n.bin, "/scene/shapes/1/file"},
                                   {n.obj_spec(), sha256_hex(n.mtl), n.mtl, "/scene/shapes/1/obj"}};
  std::vector<std::pair<ClientResponse, ClientResponse>> missing;  // validate, submit
  for (const Case& k : cases) {
    missing.emplace_back(post_json(a, "/v1/jobs/validate", k.spec), post_json(a, "/v1/jobs", k.spec));
    for (const ClientResponse& r : {missing.back().first, missing.back().second}) {
      EXPECT_EQ(r.status, 422) << r.body;
      EXPECT_EQ(json::parse(r.body).value("pointer", ""), k.pointer) << r.body;
      // Names the nested file (a glTF's loader says "File not found : sha256:<hex>").
      EXPECT_NE(problem_of(r).find("sha256:" + k.nested_hex), std::string::npos) << r.body;
    }
  }
  // Bob stores the nested files: for ann they are still not there, to the byte.
  for (const Case& k : cases) ASSERT_EQ(put(b, k.nested_hex, k.nested_bytes).status, 201);
  for (size_t i = 0; i < cases.size(); ++i) {
    const ClientResponse v = post_json(a, "/v1/jobs/validate", cases[i].spec);
    const ClientResponse s = post_json(a, "/v1/jobs", cases[i].spec);
    EXPECT_EQ(v.status, missing[i].first.status) << v.body;
    EXPECT_EQ(v.body, missing[i].first.body);
    EXPECT_EQ(s.status, missing[i].second.status) << s.body;
    EXPECT_EQ(s.body, missing[i].second.body);
  }
  // Uploaded by ann herself: the jobs run, and the nested bytes are what lights the floor.
  for (const Case& k : cases) ASSERT_EQ(put(a, k.nested_hex, k.nested_bytes).status, 201);
  for (const Case& k : cases) {
    const std::string id = submit(a, k.spec);
    wait_state(a, id, "succeeded");
    EXPECT_GT(tile_red_sum(a, id), kMinTileLight) << k.pointer;
  }
}

// Issue 27 N12: a chunked upload declares no length, and max_asset_bytes was checked
// only once the whole body was in: a 1 MB-quota user filled a 100 MB disk. Now the
// upload is refused (403, the quota's documented status) as soon as the bytes received
// pass what the quota leaves, while the client is still sending (the body's last chunk
// is never sent here), and its temp file is removed.
TEST(Assets, ChunkedUploadPastTheQuotaIsRefusedAsTheBytesArrive) {
  TempDir tmp;
  const Who ann{"ann", "user", generate_token(), 1500};
  const fs::path auth = tmp.path / "auth.json";
  std::ofstream(auth) << json{{"principals", json::array({{{"name", ann.name},
                                                            {"role", ann.role},
                                                            {"token_sha256", token_sha256_hex(ann.token)},
                                                            {"quotas", {{"max_asset_bytes", 1500}}}}})}}
                             .dump();
  ServerProcess server(tmp.path / "data", {"--auth-file", auth.string()});
  const int fd = connect_loopback(server.port(), 10);
  ASSERT_GE(fd, 0);
  const std::string part(1000, 'q');
  const std::string head = "PUT " + asset_url(sha256_hex(part + part + part)) +
                           " HTTP/1.1\r\nHost: 127.0.0.1\r\nAuthorization: Bearer " + ann.token +
                           "\r\nTransfer-Encoding: chunked\r\n\r\n";
  ASSERT_TRUE(send_all(fd, head + "3e8\r\n" + part + "\r\n"));
  std::this_thread::sleep_for(std::chrono::milliseconds(200));  // 1000 of 1500 bytes: still fine
  ASSERT_TRUE(send_all(fd, "3e8\r\n" + part + "\r\n"));      // 2000 > 1500; no last chunk follows
  std::string answer;
  char buf[4096];
  for (ssize_t n; answer.find("\r\n\r\n") == std::string::npos && (n = ::recv(fd, buf, sizeof buf, 0)) > 0;) {
    answer.append(buf, static_cast<size_t>(n));
  }
  EXPECT_EQ(answer.substr(0, 13), "HTTP/1.1 403 ") << "no answer while the body is unfinished: " << answer;
  for (ssize_t n; (n = ::recv(fd, buf, sizeof buf, 0)) > 0;) answer.append(buf, static_cast<size_t>(n));
  EXPECT_NE(answer.find("asset quota exceeded"), std::string::npos) << answer;
  ::close(fd);
  EXPECT_EQ(files_in(tmp.path / "data" / "assets" / "tmp"), 0u);
  EXPECT_EQ(files_in(tmp.path / "data" / "assets" / "sha256"), 0u);
  // What fits the quota is still stored.
  HttpClient a = server.client(ClientSecurity{ann.token, ""});
  EXPECT_EQ(put(a, sha256_hex(part), part).status, 201);
}

// Issue 27 N12: a full disk on upload answered 500. Here the data dir is a 4 MiB tmpfs
// in the server's own mount namespace (unshare -rm): a 6 MiB upload fills it and is
// answered 507 Insufficient Storage naming the cause; the partial file is removed, so
// an upload that fits is then stored.
TEST(Assets, FullDiskOnUploadIs507AndKeepsNothing) {
  if (std::system("unshare -rm true >/dev/null 2>&1") != 0) {
    GTEST_SKIP() << "cannot mount a tmpfs in a user namespace here (unshare -rm), so no disk can be filled";
  }
  TempDir tmp;
  fs::create_directories(tmp.path / "data");
  const fs::path wrapper = tmp.path / "in_small_tmpfs.sh";
  const char* other = std::getenv("TALLY_TEST_SERVER_BIN");  // another build, as ServerProcess runs it
  const bool restore = other && *other;
  const std::string bin = restore ? other : TALLY_SERVER_BIN;
  std::ofstream(wrapper) << "#!/bin/sh\nexec unshare -rm sh -c 'mount -t tmpfs -o size=4m tmpfs \"$0\" && exec \"$@\"' "
                         << (tmp.path / "data").string() << " " << bin << " \"$@\"\n";
  fs::permissions(wrapper, fs::perms::owner_all);
  ::setenv("TALLY_TEST_SERVER_BIN", wrapper.c_str(), 1);
  ServerProcess server(tmp.path / "data");
  if (restore) {
    ::setenv("TALLY_TEST_SERVER_BIN", bin.c_str(), 1);
  } else {
    ::unsetenv("TALLY_TEST_SERVER_BIN");
  }
  HttpClient c = server.client();
  std::string big(6 << 20, '\0');
  for (size_t i = 0; i < big.size(); ++i) big[i] = static_cast<char>((i * 2654435761u) >> 13);
  const int fd = connect_loopback(server.port(), 30);
  ASSERT_GE(fd, 0);
  // The answer may come before the whole body is sent: a failed send is not an error here.
  send_all(fd, "PUT " + asset_url(sha256_hex(big)) + " HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: " +
                   std::to_string(big.size()) + "\r\n\r\n" + big);
  std::string answer;
  char buf[4096];
  for (ssize_t n; (n = ::recv(fd, buf, sizeof buf, 0)) > 0;) answer.append(buf, static_cast<size_t>(n));
  ::close(fd);
  EXPECT_EQ(answer.substr(0, 13), "HTTP/1.1 507 ") << answer;
  EXPECT_NE(answer.find("the server's disk is full"), std::string::npos) << answer;
  EXPECT_EQ(c.request("HEAD", asset_url(sha256_hex(big))).status, 404);
  const std::string fits(2 << 20, 'f');  // fits only once the 4 MiB partial file is gone
  EXPECT_EQ(put(c, sha256_hex(fits), fits).status, 201);
  EXPECT_NE(server.log().find("No space left on device"), std::string::npos) << server.log();
}

TEST(Assets, CliUploadsOnlyWhatTheServerLacks) {
  if (std::string(TALLY_CLI_BIN).empty()) GTEST_SKIP() << "tally CLI not built";
  TempDir tmp;
  ServerProcess server(tmp.path / "data");
  HttpClient c = server.client();
  const std::string have = lamp_obj(1), lack = lamp_obj(3);
  ASSERT_EQ(put(c, sha256_hex(have), have).status, 201);
  fs::create_directories(tmp.path / "scene" / "meshes");
  std::ofstream(tmp.path / "scene" / "meshes" / "have.obj") << have;
  std::ofstream(tmp.path / "scene" / "meshes" / "lack.obj") << lack;
  json spec = obj_image_spec("meshes/have.obj");
  spec["scene"]["shapes"].push_back({{"type", "mesh"}, {"obj", "meshes/lack.obj"}, {"material", "floor"}});
  std::ofstream(tmp.path / "scene" / "job.json") << spec.dump(2);
  const std::string cmd = fmt::format("{} submit --server http://127.0.0.1:{} {} 2>{} >{}", TALLY_CLI_BIN,
                                      server.port(), (tmp.path / "scene" / "job.json").string(),
                                      (tmp.path / "err.txt").string(), (tmp.path / "out.txt").string());
  ASSERT_EQ(std::system(cmd.c_str()), 0);
  std::ifstream err(tmp.path / "err.txt");
  const std::string err_text(std::istreambuf_iterator<char>(err), {});
  EXPECT_NE(err_text.find("1 uploaded, 1 already on the server"), std::string::npos) << err_text;
  std::ifstream out(tmp.path / "out.txt");
  std::string id;
  out >> id;
  const json s = wait_state(c, id, "succeeded");
  const json submitted = get_json(c, "/v1/jobs/" + id).at("spec");
  EXPECT_EQ(submitted["scene"]["shapes"][1]["obj"], "sha256:" + sha256_hex(have));
  EXPECT_EQ(submitted["scene"]["shapes"][2]["obj"], "sha256:" + sha256_hex(lack));
  EXPECT_EQ(c.request("HEAD", asset_url(sha256_hex(lack))).status, 200);
  // The server's log shows one PUT that stored bytes: the asset it lacked.
  EXPECT_NE(server.log().find("asset sha256:" + sha256_hex(lack) + " stored"), std::string::npos);
  EXPECT_EQ(server.log().find("asset sha256:" + sha256_hex(have) + " already stored"), std::string::npos);
}

}  // namespace
}  // namespace tally::e2e
