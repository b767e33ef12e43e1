// Image convergence: independent vs sobol (RQMC, K replicates) sampling.
//
// For the lecture scene (examples/lecture_lighting_image.json: receiver, square lamp,
// occluder) and a Cornell-box-like scene with a sphere, at max_depth 1 and 4 (MIS, no
// roulette), on one thread:
//   * RMSE over all pixels and channels against a reference (sobol, ref_spp, another
//     seed; its own estimated variance is subtracted), averaged over `seeds` runs, for
//     spp = 8 .. 256, and the log-log slope of RMSE vs spp (least squares);
//   * the spp each sampler needs for the RMSE independent sampling reaches at 16 and 256
//     spp (log-log interpolation), times its time per sample (fastest of three
//     interleaved 96x72 x 64 spp renders), against independent's: the time-to-RMSE
//     speed-up.
// The samplers' runs are interleaved (for each spp and seed: independent, then each K),
// so the ratios come from one run under the same load.
//
//   build/bench/sampler_bench [width height ref_spp seeds [csv]]   (default 48 36 4096 2)
// With a csv path, one row per (scene, depth, sampler, spp): rmse and seconds
// (bench/sampler_plot.py turns it into docs/study/sampler_rmse_time.png).
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "common/engine/pass_loop.hpp"
#include "tests/support/cornell_box.hpp"
#include "common/lighting/image_kernel.hpp"
#include "common/lighting/lighting_spec.hpp"

using namespace tally;
using json = nlohmann::json;

namespace {

json cornell_scene() {
  json camera = scenes::cornell_camera();
  json shapes = scenes::cornell_shapes({{"type", "diffuse"}, {"albedo", {0.7, 0.1, 0.1}}});
  return {{"camera", camera}, {"materials", scenes::cornell_materials()}, {"shapes", shapes}};
}

json lecture_scene() {
  std::ifstream in(std::string(TALLY_SOURCE_DIR_BENCH) + "/examples/lecture_lighting_image.json");
  return json::parse(in)["scene"];
}

struct Run {
  std::vector<double> mean, se;  // per channel (pixel-major RGB)
  double seconds = 0;
};

Run render(json scene, int w, int h, int depth, const std::string& sampler, uint32_t k, uint64_t spp, uint64_t seed) {
  scene["camera"]["resolution"] = {w, h};
  json spec = {{"kind", "lighting"},
               {"seed", seed},
               {"sampler", sampler},
               {"scene", scene},
               {"query", {{"type", "image"}, {"max_depth", depth}, {"max_pass_spp", 256}}},
               {"estimators", {"mis"}},
               {"stop", {{"max_samples", spp}}}};
  if (sampler == "sobol") spec["replicates"] = k;
  auto job = compile_lighting_job(spec, JobLimits{});
  JobRunner runner(job->kernel(), job->stop_rule(), JobCaps{});
  const auto t0 = std::chrono::steady_clock::now();
  run_local(runner, 1);
  Run r;
  r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  r.mean.assign(3 * static_cast<size_t>(w) * static_cast<size_t>(h), 0.0);
  r.se = r.mean;
  const auto* img = dynamic_cast<const ImageKernel*>(job->image());
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      for (size_t c = 0; c < 3; ++c) {
        const ReplicatedEstimate e = img->pixel_estimate(runner.state(), img->pixel_channel(x, y), c);
        const size_t i = 3 * (static_cast<size_t>(y) * static_cast<size_t>(w) + static_cast<size_t>(x)) + c;
        r.mean[i] = e.mean;
        r.se[i] = e.has_error() ? e.std_error : 0.0;
      }
    }
  }
  return r;
}

double rmse(const Run& r, const Run& ref) {
  double ss = 0, ref_var = 0;
  for (size_t i = 0; i < r.mean.size(); ++i) {
    const double d = r.mean[i] - ref.mean[i];
    ss += d * d;
    ref_var += ref.se[i] * ref.se[i];
  }
  const double n = static_cast<double>(r.mean.size());
  return std::sqrt(std::max(0.0, ss / n - ref_var / n));
}

double slope(const std::vector<double>& x, const std::vector<double>& y) {
  double mx = 0, my = 0;
  for (size_t i = 0; i < x.size(); ++i) {
    mx += std::log(x[i]);
    my += std::log(y[i]);
  }
  mx /= static_cast<double>(x.size());
  my /= static_cast<double>(x.size());
  double sxy = 0, sxx = 0;
  for (size_t i = 0; i < x.size(); ++i) {
    sxy += (std::log(x[i]) - mx) * (std::log(y[i]) - my);
    sxx += (std::log(x[i]) - mx) * (std::log(x[i]) - mx);
  }
  return sxy / sxx;
}

// spp at which the curve (spp_i, e_i) reaches error `target` (log-log interpolation,
// extrapolated along the nearest segment outside the range).
double spp_to(const std::vector<double>& spp, const std::vector<double>& e, double target) {
  size_t i = 0;
  while (i + 2 < e.size() && e[i + 1] > target) ++i;
  const double a = std::log(e[i]), b = std::log(e[i + 1]);
  const double f = (std::log(target) - a) / (b - a);
  return std::exp(std::log(spp[i]) + f * (std::log(spp[i + 1]) - std::log(spp[i])));
}

}  // namespace

int main(int argc, char** argv) {
  const int w = argc > 1 ? std::atoi(argv[1]) : 48;
  const int h = argc > 2 ? std::atoi(argv[2]) : 36;
  const uint64_t ref_spp = argc > 3 ? std::strtoull(argv[3], nullptr, 10) : 4096;
  const int seeds = argc > 4 ? std::atoi(argv[4]) : 2;
  std::FILE* csv = argc > 5 ? std::fopen(argv[5], "w") : nullptr;
  if (csv != nullptr) std::fprintf(csv, "scene,depth,sampler,spp,rmse,seconds\n");
  const std::vector<uint64_t> spps = {8, 16, 32, 64, 128, 256};
  const std::vector<uint32_t> ks = {4, 8, 16};
  std::printf("sampler bench: %dx%d, mis, 1 thread, reference sobol K=8 at %llu spp, %d seeds per point\n", w, h,
              static_cast<unsigned long long>(ref_spp), seeds);
  struct Scene {
    std::string name;
    json scene;
  };
  const std::vector<Scene> scenes = {{"lecture", lecture_scene()}, {"cornell+sphere", cornell_scene()}};
  for (const Scene& sc : scenes) {
    for (int depth : {1, 4}) {
      const Run ref = render(sc.scene, w, h, depth, "sobol", 8, ref_spp, 999);
      // [sampler label] -> per spp: mean rmse, mean seconds
      std::map<std::string, std::vector<double>> err;
      std::vector<std::string> labels = {"independent"};
      for (uint32_t k : ks) labels.push_back("sobol K=" + std::to_string(k));
      for (const auto& l : labels) {
        err[l].assign(spps.size(), 0.0);
      }
      for (size_t i = 0; i < spps.size(); ++i) {
        for (int s = 0; s < seeds; ++s) {
          for (const auto& l : labels) {
            const bool ind = l == "independent";
            const uint32_t k = ind ? 1 : static_cast<uint32_t>(std::stoul(l.substr(8)));
            const Run r = render(sc.scene, w, h, depth, ind ? "independent" : "sobol", k, spps[i], 1 + static_cast<uint64_t>(s));
            err[l][i] += rmse(r, ref) / seeds;
          }
        }
      }
      // Time per sample: 96x72 at 64 spp, three interleaved rounds, the fastest of each.
      std::map<std::string, double> tps;
      for (int round = 0; round < 3; ++round) {
        for (const auto& l : labels) {
          const bool ind = l == "independent";
          const uint32_t k = ind ? 1 : static_cast<uint32_t>(std::stoul(l.substr(8)));
          const Run r = render(sc.scene, 96, 72, depth, ind ? "independent" : "sobol", k, 64, 77);
          const double t = r.seconds / (96.0 * 72.0 * 64.0);
          tps[l] = round == 0 ? t : std::min(tps[l], t);
        }
      }
      std::printf("\n%s, max_depth %d (reference %.2fs)\n  %-14s", sc.name.c_str(), depth, ref.seconds, "RMSE at spp");
      for (uint64_t spp : spps) std::printf(" %10llu", static_cast<unsigned long long>(spp));
      std::printf("   slope   ns/sample  spp to ind@16  ind@256   time-to-RMSE speed-up @16  @256\n");
      std::vector<double> x(spps.begin(), spps.end());
      const auto& ei = err["independent"];
      for (const auto& l : labels) {
        for (size_t i = 0; csv != nullptr && i < spps.size(); ++i) {
          std::fprintf(csv, "%s,%d,%s,%llu,%.6e,%.6e\n", sc.name.c_str(), depth, l.c_str(),
                       static_cast<unsigned long long>(spps[i]), err[l][i], tps[l] * spps[i] * w * h);
        }
        const double n16 = spp_to(x, err[l], ei[1]), n256 = spp_to(x, err[l], ei.back());
        std::printf("  %-14s", l.c_str());
        for (double e : err[l]) std::printf(" %10.3e", e);
        std::printf("  %6.3f  %9.0f  %13.1f  %7.1f   %24.2fx  %5.2fx\n", slope(x, err[l]), 1e9 * tps[l], n16, n256,
                    16.0 * tps["independent"] / (n16 * tps[l]), 256.0 * tps["independent"] / (n256 * tps[l]));
      }
    }
  }
  if (csv != nullptr) std::fclose(csv);
  return 0;
}
