// Memory per pixel of an image job (issue 28): job state (job_state_bytes, the estimate
// the limits and the server's budget use) and process peak RSS, at two resolutions of
// the same scene, and the same for Blender Cycles where `blender` is on PATH. Each
// render runs as a child process (this program with --child, or blender -b -P) so its
// peak RSS (wait4's ru_maxrss) is its own; bytes per pixel are the slope between the two
// resolutions, which cancels each program's fixed cost (code, scene, BVH).
//
//   frame_memory_bench [--small 512] [--large 2048|1920x1080] [--spp 8] [--replicates 4]
//
// tally: `tally run`'s path in process (compile_lighting_job, run_local, 1 thread),
// the default sobol sampler (K = 4 replicates, an image's default; --replicates
// sets the spec's "replicates": a pixel's state is 3 K floats), direct
// light (max_depth 1), twice: the render alone, and the render with `tally run --image`'s
// EXR written (write_exr_file: streamed a strip of rows at a time), as Cycles writes its EXR. Cycles: 1 thread,
// the given spp, the same quads and camera.
#include <sys/resource.h>
#include <sys/types.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "common/engine/job_state.hpp"
#include "common/engine/pass_loop.hpp"
#include "common/image/image_io.hpp"
#include "common/lighting/lighting_spec.hpp"
#include "common/lighting/pixel_sampler.hpp"
#include "tests/support/frame_scene.hpp"

using namespace tally;
using json = nlohmann::json;

namespace {

using scenes::frame_spec;

// The same scene for Cycles: a 6x6 diffuse floor at z = 0, a 1x1 emitter at z = 2
// facing down, the camera at (0, -4.5, 3.2) looking at (0, 0, 0.6), 50 degrees vertically.
constexpr const char* kCyclesScript = R"PY(
import bpy, sys, mathutils
w, h, spp, out = int(sys.argv[-4]), int(sys.argv[-3]), int(sys.argv[-2]), sys.argv[-1]
bpy.ops.wm.read_factory_settings(use_empty=True)
sc = bpy.context.scene
sc.render.engine = 'CYCLES'
sc.cycles.device = 'CPU'
sc.cycles.samples = spp
sc.cycles.use_adaptive_sampling = False
sc.cycles.use_denoising = False
sc.cycles.max_bounces = 1
sc.render.threads_mode = 'FIXED'
sc.render.threads = 1
sc.render.resolution_x, sc.render.resolution_y, sc.render.resolution_percentage = w, h, 100
sc.render.image_settings.file_format = 'OPEN_EXR'
sc.render.filepath = out
def quad(name, corner, eu, ev, mat):
    c, u, v = map(mathutils.Vector, (corner, eu, ev))
    me = bpy.data.meshes.new(name)
    me.from_pydata([c, c + u, c + u + v, c + v], [], [(0, 1, 2, 3)])
    ob = bpy.data.objects.new(name, me)
    ob.data.materials.append(mat)
    sc.collection.objects.link(ob)
white = bpy.data.materials.new('white'); white.use_nodes = True
nt = white.node_tree; nt.nodes.clear()
df = nt.nodes.new('ShaderNodeBsdfDiffuse'); df.inputs['Color'].default_value = (0.8, 0.8, 0.8, 1)
mo = nt.nodes.new('ShaderNodeOutputMaterial'); nt.links.new(df.outputs[0], mo.inputs[0])
lamp = bpy.data.materials.new('lamp'); lamp.use_nodes = True
nt = lamp.node_tree; nt.nodes.clear()
em = nt.nodes.new('ShaderNodeEmission'); em.inputs['Color'].default_value = (1, 1, 1, 1); em.inputs['Strength'].default_value = 5
mo = nt.nodes.new('ShaderNodeOutputMaterial'); nt.links.new(em.outputs[0], mo.inputs[0])
quad('floor', (-3, -3, 0), (6, 0, 0), (0, 6, 0), white)
quad('lamp', (-0.5, -0.5, 2), (0, 1, 0), (1, 0, 0), lamp)
cam = bpy.data.objects.new('cam', bpy.data.cameras.new('cam'))
sc.collection.objects.link(cam); sc.camera = cam
cam.location = (0, -4.5, 3.2)
cam.rotation_euler = (mathutils.Vector((0, 0, 0.6)) - cam.location).to_track_quat('-Z', 'Y').to_euler()
cam.data.sensor_fit = 'VERTICAL'  # tally's fov_deg is vertical (scene.hpp)
import math; cam.data.angle = math.radians(50)
bpy.ops.render.render(write_still=True)
)PY";

struct Child {
  bool ok = false;
  double seconds = 0;
  uint64_t peak_rss = 0;  // bytes
};

// Runs argv, waits, returns its own peak RSS.
Child run_child(const std::vector<std::string>& args, bool quiet) {
  const auto t0 = std::chrono::steady_clock::now();
  const pid_t pid = fork();
  if (pid < 0) return {};
  if (pid == 0) {
    if (quiet) {
      std::FILE* devnull = std::fopen("/dev/null", "w");
      if (devnull) {
        dup2(fileno(devnull), 1);
        dup2(fileno(devnull), 2);
      }
    }
    std::vector<char*> argv;
    for (const std::string& a : args) argv.push_back(const_cast<char*>(a.c_str()));
    argv.push_back(nullptr);
    execvp(argv[0], argv.data());
    _exit(127);
  }
  int status = 0;
  rusage ru{};
  if (wait4(pid, &status, 0, &ru) != pid) return {};
  Child c;
  c.ok = WIFEXITED(status) && WEXITSTATUS(status) == 0;
  c.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  c.peak_rss = static_cast<uint64_t>(ru.ru_maxrss) * 1024;  // Linux: kilobytes
  return c;
}

bool on_path(const std::string& name) {
  const char* path = std::getenv("PATH");
  if (!path) return false;
  std::string p(path);
  for (size_t a = 0; a <= p.size();) {
    const size_t b = p.find(':', a);
    const std::string dir = p.substr(a, b == std::string::npos ? std::string::npos : b - a);
    if (!dir.empty() && access((std::filesystem::path(dir) / name).c_str(), X_OK) == 0) return true;
    if (b == std::string::npos) break;
    a = b + 1;
  }
  return false;
}

JobLimits unlimited_state() {
  JobLimits l;
  l.max_state_bytes = UINT64_MAX;
  return l;
}

json spec_with(int w, int h, uint64_t spp, uint32_t replicates) {
  json spec = frame_spec(w, h, spp);
  spec["replicates"] = replicates;
  return spec;
}

// `exr`: "" renders only; else the image is written there as `tally run --image` does.
int child_main(int w, int h, uint64_t spp, uint32_t replicates, const std::string& exr) {
  auto job = compile_lighting_job(spec_with(w, h, spp, replicates), unlimited_state());
  JobRunner runner(job->kernel(), job->stop_rule(), JobCaps{});
  LocalRunOptions o;
  o.threads = 1;
  run_local(runner, o);
  if (runner.state().samples != spp) return 1;
  if (exr.empty()) return 0;
  write_exr_file(*job->image(), runner.state(), {{"samples", runner.state().samples}}, exr);
  return 0;
}

double per_pixel(uint64_t a, uint64_t b, uint64_t pa, uint64_t pb) {
  return (static_cast<double>(b) - static_cast<double>(a)) / static_cast<double>(pb - pa);
}

// Prints a program's two peaks and their slope; nullopt (said) if a run failed.
std::optional<double> peak_per_pixel(const char* name, const Child& small, const Child& large, uint64_t ps,
                                     uint64_t pl) {
  if (!small.ok || !large.ok) {
    std::printf("%s failed\n", name);
    return std::nullopt;
  }
  const double bpp = per_pixel(small.peak_rss, large.peak_rss, ps, pl);
  std::printf("%s peak RSS: %.1f MB (%.1f s), %.1f MB (%.1f s): %.1f bytes/pixel\n", name, small.peak_rss / 1e6,
              small.seconds, large.peak_rss / 1e6, large.seconds, bpp);
  return bpp;
}

struct Size {
  int w = 0, h = 0;
  uint64_t pixels() const { return uint64_t(w) * uint64_t(h); }
  std::string text() const { return std::to_string(w) + "x" + std::to_string(h); }
};

// "512" (square) or "1920x1080".
Size parse_size(const std::string& s) {
  const size_t x = s.find('x');
  if (x == std::string::npos) return {std::atoi(s.c_str()), std::atoi(s.c_str())};
  return {std::atoi(s.substr(0, x).c_str()), std::atoi(s.substr(x + 1).c_str())};
}

}  // namespace

int main(int argc, char** argv) {
  Size small{512, 512}, large{2048, 2048};
  uint64_t spp = 8;
  uint32_t replicates = kDefaultImageReplicates;
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string f = argv[i];
    if (f == "--child" && i + 4 < argc) {
      return child_main(std::atoi(argv[i + 1]), std::atoi(argv[i + 2]), std::strtoull(argv[i + 3], nullptr, 10),
                        static_cast<uint32_t>(std::atoi(argv[i + 4])), i + 5 < argc ? argv[i + 5] : "");
    }
    if (f == "--small") small = parse_size(argv[i + 1]);
    else if (f == "--large") large = parse_size(argv[i + 1]);
    else if (f == "--spp") spp = std::strtoull(argv[i + 1], nullptr, 10);
    else if (f == "--replicates") replicates = static_cast<uint32_t>(std::atoi(argv[i + 1]));
  }
  if (small.w <= 0 || small.h <= 0 || large.pixels() <= small.pixels() || replicates < 2 || spp < replicates) {
    std::fprintf(stderr,
                 "usage: frame_memory_bench [--small 512] [--large 2048|1920x1080] [--spp 8] [--replicates 4] "
                 "(2 <= replicates <= spp)\n");
    return 2;
  }
  const uint64_t ps = small.pixels(), pl = large.pixels();
  std::printf("frame_memory_bench: %s and %s, %llu spp, %u replicates, 1 thread, direct light\n",
              small.text().c_str(), large.text().c_str(), static_cast<unsigned long long>(spp), replicates);
  // The state estimate as the limits compute it (32-pixel tiles).
  const auto state = [&](Size s) {
    auto job = compile_lighting_job(spec_with(s.w, s.h, spp, replicates), unlimited_state());
    return job_state_bytes(job->kernel()->channel_count(), job->kernel()->partition_count(), job->kernel()->sum_count());
  };
  const uint64_t ss = state(small), sl = state(large);
  std::printf("tally job state (job_state_bytes): %.1f MB, %.1f MB: %.1f bytes/pixel\n", ss / 1e6, sl / 1e6,
              per_pixel(ss, sl, ps, pl));
  const std::string self = std::filesystem::canonical("/proc/self/exe").string();
  const bool cycles = on_path("blender");
  const std::filesystem::path dir = std::filesystem::temp_directory_path() / ("frame_memory_bench." + std::to_string(getpid()));
  std::filesystem::create_directories(dir);
  if (cycles) std::ofstream(dir / "scene.py") << kCyclesScript;
  const auto tally_run = [&](Size s, bool exr) {
    std::vector<std::string> args = {self,          "--child",           std::to_string(s.w), std::to_string(s.h),
                                     std::to_string(spp), std::to_string(replicates)};
    if (exr) args.push_back((dir / "tally.exr").string());
    return run_child(args, false);
  };
  const auto cycles_run = [&](Size s) {
    return run_child({"blender", "-b", "--factory-startup", "-P", (dir / "scene.py").string(), "--", std::to_string(s.w),
                      std::to_string(s.h), std::to_string(spp), (dir / "out.exr").string()},
                     true);
  };
  // Interleaved (tally, Cycles at the small size, then both at the large one) so that
  // whatever else the machine does between runs falls on both programs alike.
  const Child ts = tally_run(small, false);
  const Child te = tally_run(small, true);
  const Child cs = cycles ? cycles_run(small) : Child{};
  const Child tl = tally_run(large, false);
  const Child tle = tally_run(large, true);
  const Child cl = cycles ? cycles_run(large) : Child{};
  std::filesystem::remove_all(dir);
  const std::optional<double> tally_bpp = peak_per_pixel("tally", ts, tl, ps, pl);
  const std::optional<double> exr_bpp = peak_per_pixel("tally with its EXR", te, tle, ps, pl);
  if (!tally_bpp || !exr_bpp) return 1;
  if (!cycles) {
    std::printf("blender is not on PATH: Cycles not measured\n");
    return 0;
  }
  const std::optional<double> cycles_bpp = peak_per_pixel("Cycles (its EXR written)", cs, cl, ps, pl);
  if (!cycles_bpp) return 1;
  std::printf("tally / Cycles bytes per pixel of peak RSS: %.2f render alone, %.2f with the EXR written (goal <= 1.0)\n",
              *tally_bpp / *cycles_bpp, *exr_bpp / *cycles_bpp);
  return 0;
}
