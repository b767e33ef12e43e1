// asset_bench: the issue-16 large-scene figures.
//   1. Writes a 1-million-triangle OBJ (a tessellated terrain, 708 x 708 quads).
//   2. Starts tally-server (temp data dir), uploads the file with PUT
//      /v1/assets/sha256:<hex> (streamed from disk), times it, and renders a small image
//      of a scene that names it by hash: time to succeed, and the server's peak RSS
//      (VmHWM) after the upload and after the render.
//   3. In this process: the OBJ parsed into a Scene, then tally's Accel build (what a job
//      does) against a bare Embree build of the same triangles (rtcNewScene,
//      rtcCommitScene; default quality, and the same ROBUST + HIGH quality tally uses),
//      interleaved, median of N rounds each, and their ratios.
// Usage: asset_bench [rounds=5] [quads_per_side=708]
#include <embree3/rtcore.h>
#include <fmt/format.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <thread>
#include <vector>

#include "client/asset_upload.hpp"
#include "client/http_client.hpp"
#include "common/lighting/accel.hpp"
#include "common/lighting/embree_device.hpp"
#include "common/lighting/scene_json.hpp"
#include "common/lighting/localize_scene.hpp"
#include "common/spec/spec_reader.hpp"

namespace fs = std::filesystem;
using nlohmann::json;
using clk = std::chrono::steady_clock;

namespace {

double since(clk::time_point t0) { return std::chrono::duration<double>(clk::now() - t0).count(); }

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

long vm_hwm_kib(pid_t pid) {
  std::ifstream in(fmt::format("/proc/{}/status", pid));
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind("VmHWM:", 0) == 0) return std::stol(line.substr(6));
  }
  return -1;
}

void write_terrain(const fs::path& path, int n) {
  std::ofstream o(path);
  o.precision(7);
  for (int j = 0; j <= n; ++j) {
    for (int i = 0; i <= n; ++i) {
      const double x = -1.0 + 2.0 * i / n, y = -1.0 + 2.0 * j / n;
      o << "v " << x << ' ' << y << ' ' << 0.1 * std::sin(7 * x) * std::cos(5 * y) << '\n';
    }
  }
  for (int j = 0; j < n; ++j) {
    for (int i = 0; i < n; ++i) {
      const int a = j * (n + 1) + i + 1, b = a + 1, c = a + n + 1, d = c + 1;
      o << "f " << a << ' ' << b << ' ' << d << "\nf " << a << ' ' << d << ' ' << c << '\n';
    }
  }
}

double bare_embree_build(const tally::Shape& s, bool tally_quality) {
  const auto t0 = clk::now();
  RTCDevice dev = tally::embree_device();
  RTCScene sc = rtcNewScene(dev);
  if (tally_quality) {
    rtcSetSceneFlags(sc, RTC_SCENE_FLAG_ROBUST);
    rtcSetSceneBuildQuality(sc, RTC_BUILD_QUALITY_HIGH);
  }
  RTCGeometry g = rtcNewGeometry(dev, RTC_GEOMETRY_TYPE_TRIANGLE);
  auto* vb = static_cast<float*>(
      rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float), s.vertices.size()));
  auto* ib = static_cast<unsigned*>(rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                                            3 * sizeof(unsigned), s.triangles.size()));
  for (size_t i = 0; i < s.vertices.size(); ++i) {
    for (int k = 0; k < 3; ++k) vb[3 * i + k] = static_cast<float>(s.vertices[i][k]);
  }
  for (size_t i = 0; i < s.triangles.size(); ++i) {
    for (int k = 0; k < 3; ++k) ib[3 * i + k] = s.triangles[i][k];
  }
  rtcCommitGeometry(g);
  rtcAttachGeometry(sc, g);
  rtcReleaseGeometry(g);
  rtcCommitScene(sc);
  const double dt = since(t0);
  rtcReleaseScene(sc);
  return dt;
}

struct Server {
  pid_t pid = -1;
  uint16_t port = 0;
  Server(const fs::path& dir) {
    const fs::path port_file = dir / "port";
    std::fflush(stdout);  // the child must not print this process's buffered lines again
    pid = ::fork();
    if (pid == 0) {
      const std::string data = (dir / "data").string(), pf = port_file.string(), log = (dir / "server.log").string();
      std::freopen(log.c_str(), "w", stdout);
      std::freopen(log.c_str(), "a", stderr);
      ::execl(TALLY_SERVER_BIN, TALLY_SERVER_BIN, "--listen", "127.0.0.1:0", "--port-file", pf.c_str(), "--data-dir",
              data.c_str(), "--workers", "2", "--max-asset-bytes", "4000000000", static_cast<char*>(nullptr));
      ::_exit(127);
    }
    for (int i = 0; i < 3000 && port == 0; ++i) {
      std::ifstream in(port_file);
      int p = 0;
      if (in >> p) port = static_cast<uint16_t>(p);
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    if (port == 0) throw std::runtime_error("tally-server did not start");
  }
  ~Server() {
    ::kill(pid, SIGTERM);
    int st = 0;
    ::waitpid(pid, &st, 0);
  }
};

}  // namespace

int main(int argc, char** argv) {
  const int rounds = argc > 1 ? std::atoi(argv[1]) : 5;
  const int n = argc > 2 ? std::atoi(argv[2]) : 708;
  const fs::path dir = fs::temp_directory_path() / fmt::format("tally_asset_bench_{}", ::getpid());
  fs::create_directories(dir);
  const fs::path obj = dir / "terrain.obj";
  auto t0 = clk::now();
  write_terrain(obj, n);
  const uint64_t tris = 2ULL * n * n;
  fmt::print("mesh: {} triangles, {} vertices, OBJ {:.1f} MB (written in {:.2f} s)\n", tris,
             static_cast<uint64_t>(n + 1) * (n + 1), fs::file_size(obj) / 1e6, since(t0));

  // --- over HTTP
  {
    Server server(dir);
    tally::HttpUrl url;
    url.port = std::to_string(server.port);
    tally::HttpClient c(url, 300);
    const long rss0 = vm_hwm_kib(server.pid);
    t0 = clk::now();
    const std::string hex = tally::sha256_file_hex(obj);
    const double t_hash = since(t0);
    t0 = clk::now();
    const tally::ClientResponse put = c.send_file("PUT", "/v1/assets/sha256:" + hex, obj.string());
    const double t_put = since(t0);
    if (put.status != 201) throw std::runtime_error("upload failed: " + put.body);
    const long rss_upload = vm_hwm_kib(server.pid);
    fmt::print("upload: PUT {:.1f} MB in {:.2f} s ({:.0f} MB/s; hashing on the client {:.2f} s); server peak RSS "
               "{:.0f} MB before, {:.0f} MB after the upload\n",
               fs::file_size(obj) / 1e6, t_put, fs::file_size(obj) / 1e6 / t_put, t_hash, rss0 / 1024.0,
               rss_upload / 1024.0);
    const json spec = {
        {"kind", "lighting"},
        {"seed", 1},
        {"scene",
         {{"camera",
           {{"position", {0, -2.5, 1.5}}, {"look_at", {0, 0, 0}}, {"up", {0, 0, 1}}, {"fov_deg", 50},
            {"resolution", {64, 48}}}},
          {"materials",
           {{"ground", {{"type", "diffuse"}, {"albedo", {0.7, 0.7, 0.7}}}},
            {"lamp", {{"type", "emissive"}, {"radiance", {5, 5, 5}}}}}},
          {"shapes",
           json::array({{{"type", "mesh"}, {"obj", "sha256:" + hex}, {"material", "ground"}},
                        {{"type", "quad"}, {"corner", {-0.5, -0.5, 2}}, {"edge_u", {0, 1, 0}}, {"edge_v", {1, 0, 0}},
                         {"material", "lamp"}}})}}},
        {"query", {{"type", "image"}, {"max_depth", 2}}},
        {"estimators", {"mis"}},
        {"stop", {{"max_samples", 4}}}};  // per pixel
    t0 = clk::now();
    const tally::ClientResponse sub = c.request("POST", "/v1/jobs", spec.dump(), {{"Content-Type", "application/json"}});
    if (sub.status != 202) throw std::runtime_error("submit failed: " + sub.body);
    const double t_submit = since(t0);
    const std::string id = json::parse(sub.body).at("id");
    std::string state;
    for (int i = 0; i < 6000 && state != "succeeded" && state != "failed"; ++i) {
      state = json::parse(c.request("GET", "/v1/jobs/" + id).body).at("state");
      if (state != "succeeded") std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    fmt::print("render: POST /v1/jobs (parse the OBJ, build, plan) {:.2f} s; 64x48 at 4 spp done in {:.2f} s ({}); "
               "server peak RSS {:.0f} MB\n",
               t_submit, since(t0), state, vm_hwm_kib(server.pid) / 1024.0);
  }

  // --- Embree build: tally's Accel against bare Embree, interleaved.
  tally::JobLimits limits;
  limits.asset_dir = dir.string();
  const json scene_json = {{"materials", {{"m", {{"type", "diffuse"}, {"albedo", {0.5, 0.5, 0.5}}}}}},
                           {"shapes", json::array({{{"type", "mesh"}, {"obj", "terrain.obj"}, {"material", "m"}}})}};
  t0 = clk::now();
  tally::SpecReader r(scene_json, "/scene");
  tally::Scene scene = tally::parse_scene(r, limits);
  tally::localize_scene(scene);
  fmt::print("parse: OBJ -> Scene in {:.2f} s (in this process)\n", since(t0));
  std::vector<double> t_tally, t_bare, t_bare_hq;
  (void)bare_embree_build(scene.shapes[0], false);  // warm-up (device, thread pool)
  for (int i = 0; i < rounds; ++i) {
    t0 = clk::now();
    { tally::Accel accel(scene); }
    t_tally.push_back(since(t0));
    t_bare.push_back(bare_embree_build(scene.shapes[0], false));
    t_bare_hq.push_back(bare_embree_build(scene.shapes[0], true));
  }
  const double mt = median(t_tally), mb = median(t_bare), mh = median(t_bare_hq);
  fmt::print("embree build ({} rounds, interleaved, medians): tally Accel {:.3f} s; bare Embree default quality {:.3f} s "
             "(ratio {:.2f}); bare Embree ROBUST+HIGH as tally {:.3f} s (ratio {:.2f})\n",
             rounds, mt, mb, mt / mb, mh, mt / mh);
  fmt::print("bench process peak RSS {:.0f} MB\n", vm_hwm_kib(::getpid()) / 1024.0);
  fs::remove_all(dir);
  return 0;
}
