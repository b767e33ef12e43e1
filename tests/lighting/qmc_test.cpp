// The sobol sampler (RQMC, K replicates per pixel / point): its error bars are honest
// (coverage of 95% intervals on a closed form, for images and point queries, and for jobs
// stopped by error targets), its results are bit-identical for any thread count and
// across a resume, and a bad "sampler" names its field.
//
// Closed form: a one-sided quad light facing down over a Lambertian plane, nothing else
// (the planner turns shadow rays off). A pixel's exact value is the average over its
// footprint of rho/pi * E(P), E from Lambert's formula at the point P the camera ray
// hits; the average is a 10x10 Gauss-Legendre rule (the integrand is smooth and
// analytic over a pixel: 1e-12 relative).
//
// Coverage tests count pixel-seed pairs (or point-seed pairs) whose 95% interval
// contains the exact value. Each pair has independent randomizations, so if the intervals
// are right the count is Binomial(N, 0.95); the accepted band [0.93, 0.97] is more than
// 8 standard deviations wide at N >= 8192 (false-failure rate < 1e-15). Seeds are fixed:
// the tests are deterministic.
#include <gtest/gtest.h>

#include <fmt/format.h>

#include <boost/math/quadrature/gauss.hpp>

#include "common/engine/checkpoint.hpp"
#include "common/protocol/job_kinds.hpp"
#include "common/spec/spec_reader.hpp"
#include "common/lighting/image_kernel.hpp"
#include "common/lighting/point_kernel.hpp"
#include "common/stats/replicates.hpp"
#include "lighting/lighting_test_support.hpp"

namespace tally::test {
namespace {

constexpr double kRho = 0.7, kLe = 4.0;
const std::vector<Vec3> kLight = {{-0.5, 1.5, 1.5}, {-0.5, 2.5, 1.5}, {0.5, 2.5, 1.5}, {0.5, 1.5, 1.5}};
const Vec3 kCamPos{0, -1, 1}, kCamAt{0, 0.6, 0};
constexpr double kFov = 40;

json plane_scene(int w, int h) {
  // The light's normal edge_u x edge_v = (0,1,0) x (1,0,0) = (0,0,-1): facing the plane.
  return {{"camera", {{"position", vec(kCamPos)}, {"look_at", vec(kCamAt)}, {"fov_deg", kFov}, {"resolution", {w, h}}}},
          {"materials", {{"floor", diffuse(kRho)}, {"lamp", emitter(kLe)}}},
          {"shapes", json::array({
                         {{"type", "quad"}, {"corner", {-20, -20, 0}}, {"edge_u", {40, 0, 0}}, {"edge_v", {0, 40, 0}}, {"material", "floor"}},
                         {{"type", "quad"}, {"corner", {-0.5, 1.5, 1.5}}, {"edge_u", {0, 1, 0}}, {"edge_v", {1, 0, 0}}, {"material", "lamp"}},
                     })}};
}

json image_spec(int w, int h, uint64_t seed, const std::string& estimator, const json& stop) {
  return {{"kind", "lighting"},
          {"seed", seed},
          {"sampler", "sobol"},
          {"scene", plane_scene(w, h)},
          {"query", {{"type", "image"}, {"max_depth", 1}, {"tile_size", 16}}},
          {"estimators", {estimator}},
          {"stop", stop}};
}

double radiance_at(const Vec3& p) { return kRho / kPi * lambert_irradiance(kLight, p, {0, 0, 1}, kLe); }

// Radiance through the image point (x + u, y + v), the same camera model as ImageKernel.
double radiance_through(int w, int h, double px, double py) {
  const Vec3 fwd = normalize(kCamAt - kCamPos);
  const Vec3 right = normalize(cross(fwd, Vec3{0, 1, 0}));
  const Vec3 up = cross(right, fwd);
  const double tan_half = std::tan(0.5 * kFov * kPi / 180.0), aspect = static_cast<double>(w) / h;
  const double sx = (2.0 * px / w - 1.0) * tan_half * aspect;
  const double sy = (1.0 - 2.0 * py / h) * tan_half;
  const Vec3 d = normalize(fwd + right * sx + up * sy);
  const double t = -kCamPos.z / d.z;
  return radiance_at(kCamPos + d * t);
}

// Exact pixel values: 10x10 Gauss-Legendre over each pixel's footprint.
std::vector<double> exact_pixels(int w, int h) {
  std::vector<double> out(static_cast<size_t>(w) * static_cast<size_t>(h));
  using GL = boost::math::quadrature::gauss<double, 10>;
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      out[static_cast<size_t>(y) * static_cast<size_t>(w) + static_cast<size_t>(x)] = GL::integrate(
          [&](double v) { return GL::integrate([&](double u) { return radiance_through(w, h, x + u, y + v); }, 0.0, 1.0); },
          0.0, 1.0);
    }
  }
  return out;
}

struct Coverage {
  uint64_t inside = 0, total = 0;
  double sum_abs_z = 0;  // distinguishes runs with equal counts
  double sum_sq_error = 0;  // of the pixel means: the image's RMSE
  double fraction() const { return static_cast<double>(inside) / static_cast<double>(total); }
};

void count_image(const JobRun& r, const std::vector<double>& exact, int w, int h, uint32_t replicates,
                 Coverage& cov) {
  const auto* img = dynamic_cast<const ImageKernel*>(r.job->image());
  ASSERT_NE(img, nullptr);
  ASSERT_EQ(img->replicates(), replicates);
  const JobState& st = r.runner->state();
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const ReplicatedEstimate e = img->pixel_estimate(st, img->pixel_channel(x, y), 0);
      ASSERT_TRUE(e.has_error());
      const double ex = exact[static_cast<size_t>(y) * static_cast<size_t>(w) + static_cast<size_t>(x)];
      cov.inside += std::fabs(e.mean - ex) <= e.half_width(0.95) ? 1 : 0;
      cov.sum_abs_z += std::fabs(e.mean - ex) / e.std_error;
      cov.sum_sq_error += (e.mean - ex) * (e.mean - ex);
      cov.total += 1;
    }
  }
}

// `replicates`: the spec's "replicates" K (t with K - 1 dof), the default when it is the default.
void expect_image_coverage(const std::string& estimator, uint64_t spp, int seeds,
                           uint32_t replicates = kDefaultImageReplicates, double lowest = 0.93) {
  constexpr int w = 32, h = 32;
  const std::vector<double> exact = exact_pixels(w, h);
  Coverage cov;
  for (int s = 0; s < seeds; ++s) {
    json spec = image_spec(w, h, 1000 + static_cast<uint64_t>(s), estimator, {{"max_samples", spp}});
    if (replicates != kDefaultImageReplicates) spec["replicates"] = replicates;
    const JobRun r = run_spec(spec);
    ASSERT_EQ(r.runner->state().samples, spp);
    EXPECT_EQ(r.counter(LightingCounter::shadow_rays), 0u);
    count_image(r, exact, w, h, replicates, cov);
  }
  std::printf("  %s %llu spp, K = %u: %llu / %llu pixel-seed intervals contain the exact value (%.4f); mean |z| %.4f; "
              "RMSE %.4g\n",
              estimator.c_str(), static_cast<unsigned long long>(spp), replicates,
              static_cast<unsigned long long>(cov.inside),
              static_cast<unsigned long long>(cov.total), cov.fraction(), cov.sum_abs_z / static_cast<double>(cov.total),
              std::sqrt(cov.sum_sq_error / static_cast<double>(cov.total)));
  EXPECT_GE(cov.fraction(), lowest);
  EXPECT_LE(cov.fraction(), 0.97);
}

TEST(QmcCoverage, ExactPixelValuesAreRight) {
  // The reference itself has converged: 10- and 20-point Gauss-Legendre agree to 1e-11.
  constexpr int w = 8, h = 8;
  const std::vector<double> a = exact_pixels(w, h);
  using GL = boost::math::quadrature::gauss<double, 20>;
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const double b = GL::integrate(
          [&](double v) { return GL::integrate([&](double u) { return radiance_through(w, h, x + u, y + v); }, 0.0, 1.0); },
          0.0, 1.0);
      const double v = a[static_cast<size_t>(y * w + x)];
      EXPECT_GT(v, 1e-3);
      EXPECT_NEAR(v, b, 1e-11 * v) << x << "," << y;
    }
  }
}

TEST(QmcCoverage, ImageIntervals16spp) { expect_image_coverage("light_area", 16, 8); }
TEST(QmcCoverage, ImageIntervals256spp) { expect_image_coverage("light_area", 256, 8); }
TEST(QmcCoverage, ImageIntervalsMis16spp) { expect_image_coverage("mis", 16, 8); }
TEST(QmcCoverage, ImageIntervalsMis256spp) { expect_image_coverage("mis", 256, 8); }
// The BSDF-sampled estimators find the small light by chance: with the default K = 4 their
// 256-spp intervals cover 0.936 (uniform) and 0.924 (cosine), K = 8 0.945 / 0.944 (at
// 16 spp both K cover under 0.5: most replicates see no light). Stated, not hidden
// (docs/lighting.md): the bound here is 0.90, about 4 sd of the 8,192 pixel-seed pairs
// below what is measured.
TEST(QmcCoverage, HemisphereImageIntervals256sppUnderCoverWithFourReplicates) {
  expect_image_coverage("uniform_hemisphere", 256, 8, kDefaultImageReplicates, 0.90);
  expect_image_coverage("cosine_hemisphere", 256, 8, kDefaultImageReplicates, 0.90);
}
// K = 8 replicates (the default before results version 5; twice the state a pixel), t with 7 dof.
TEST(QmcCoverage, ImageIntervalsEightReplicates16spp) { expect_image_coverage("mis", 16, 8, 8); }
TEST(QmcCoverage, ImageIntervalsEightReplicates256spp) { expect_image_coverage("mis", 256, 8, 8); }

Vec3 query_point(size_t i) { return {-0.7 + 0.2 * static_cast<double>(i), 0.4 + 0.25 * static_cast<double>(i), 0}; }

json point_query_spec(uint64_t seed, uint64_t samples, const std::vector<std::string>& estimators, const json& stop,
                      size_t first_point = 0, size_t n_points = 8) {
  json pts = json::array();
  for (size_t i = first_point; i < first_point + n_points; ++i) {
    pts.push_back({{"p", vec(query_point(i))}, {"n", {0, 0, 1}}, {"material", "floor"}});
  }
  json scene = plane_scene(4, 4);
  scene.erase("camera");
  json spec = {{"kind", "lighting"},
               {"seed", seed},
               {"sampler", "sobol"},
               {"scene", scene},
               {"query", {{"type", "points"}, {"points", pts}}},
               {"estimators", estimators},
               {"stop", stop}};
  if (samples > 0) spec["stop"]["max_samples"] = samples;
  return spec;
}

TEST(QmcCoverage, PointQueriesOverAThousandSeeds) {
  const std::vector<std::string> est = {"uniform_hemisphere", "cosine_hemisphere", "light_area", "mis"};
  std::vector<Coverage> cov(est.size());
  std::vector<double> exact(8);
  for (size_t i = 0; i < 8; ++i) exact[i] = radiance_at(query_point(i));
  for (uint64_t s = 0; s < 1000; ++s) {
    const JobRun r = run_spec(point_query_spec(s + 1, 128, est, json::object()));
    const auto& pk = dynamic_cast<const PointKernel&>(r.runner->kernel());
    ASSERT_EQ(pk.replicates(), kDefaultPointReplicates);
    for (size_t e = 0; e < est.size(); ++e) {
      for (size_t k = 0; k < 8; ++k) {
        const ReplicatedEstimate x = pk.estimate(r.runner->state(), e, k, 0);
        ASSERT_EQ(x.n, 128u);
        cov[e].inside += std::fabs(x.mean - exact[k]) <= x.half_width(0.95) ? 1 : 0;
        cov[e].total += 1;
      }
    }
  }
  for (size_t e = 0; e < est.size(); ++e) {
    std::printf("  %-18s 128 samples: %llu / %llu point-seed intervals contain the exact value (%.4f)\n",
                est[e].c_str(), static_cast<unsigned long long>(cov[e].inside),
                static_cast<unsigned long long>(cov[e].total), cov[e].fraction());
    EXPECT_GE(cov[e].fraction(), 0.93) << est[e];
    EXPECT_LE(cov[e].fraction(), 0.97) << est[e];
  }
}

TEST(QmcCoverage, PointErrorTargetsStopWithTheTrueErrorWithinTarget) {
  // Jobs of one point each (cycling through the 8 points), light_area and mis, stopped by
  // rel_error: the target is set so that jobs stop after one to three passes (the first
  // pass alone does not reach it). Every job reports target_met; the exact value is
  // within the target of the estimate for >= 90% of them (>= 95% expected), and within the job's final 95%
  // interval (which optional stopping could bias) for 0.90-0.99 of them (N = 200:
  // sd 0.015; 0.90 is 3.2 sd below 0.95, a false-failure rate < 1e-3 per estimator).
  for (const auto& [est, target] : {std::pair<std::string, double>{"light_area", 1e-5}, {"mis", 1.5e-4}}) {
    uint64_t within = 0, covered = 0, total = 0, passes = 0;
    for (uint64_t s = 0; s < 200; ++s) {
      const size_t k = s % 8;
      const JobRun r = run_spec(point_query_spec(5000 + s, 0, {est}, {{"rel_error", target}}, k, 1));
      ASSERT_EQ(r.runner->stop_reason(), StopReason::error_target);
      ASSERT_TRUE(r.runner->target_met());
      const auto& pk = dynamic_cast<const PointKernel&>(r.runner->kernel());
      const ReplicatedEstimate x = pk.estimate(r.runner->state(), 0, 0, 0);
      const double err = std::fabs(x.mean - radiance_at(query_point(k)));
      within += err <= target * std::fabs(x.mean) ? 1 : 0;
      covered += err <= x.half_width(0.95) ? 1 : 0;
      passes += r.runner->state().passes;
      ++total;
    }
    const double f = static_cast<double>(within) / static_cast<double>(total);
    const double c = static_cast<double>(covered) / static_cast<double>(total);
    std::printf("  %s rel_error %.2g: %.2f passes on average; true error within target for %.4f, within the final "
                "interval for %.4f of %llu jobs\n",
                est.c_str(), target, static_cast<double>(passes) / static_cast<double>(total), f, c,
                static_cast<unsigned long long>(total));
    EXPECT_GE(f, 0.90) << est;
    EXPECT_GE(c, 0.90) << est;
    EXPECT_LE(c, 0.99) << est;
  }
}

TEST(QmcCoverage, AdaptiveImageStopsWithPixelsWithinTarget) {
  // Adaptive tiles with a per-pixel target: when the job stops by error_target, each
  // pixel's true relative error (RGB average) is within the target for >= 90% of
  // pixel-seed pairs (expected >= 95%: a pixel stops only once its interval is inside).
  constexpr int w = 32, h = 32;
  const std::vector<double> exact = exact_pixels(w, h);
  const double target = 0.05;
  uint64_t within = 0, total = 0;
  for (uint64_t s = 0; s < 6; ++s) {
    json spec = image_spec(w, h, 300 + s, "light_area", {{"max_samples", 4096}});
    spec["query"]["adaptive"] = {{"rel_error", target}, {"min_spp", 16}};
    spec["query"]["tile_size"] = 4;
    const JobRun r = run_spec(spec);
    ASSERT_EQ(r.runner->stop_reason(), StopReason::error_target);
    const auto* img = dynamic_cast<const ImageKernel*>(r.job->image());
    for (int y = 0; y < h; ++y) {
      for (int x = 0; x < w; ++x) {
        const ReplicatedEstimate e = img->pixel_estimate(r.runner->state(), img->pixel_channel(x, y), 0);
        const double ex = exact[static_cast<size_t>(y) * w + static_cast<size_t>(x)];
        within += std::fabs(e.mean - ex) <= target * std::fabs(e.mean) ? 1 : 0;
        ++total;
      }
    }
  }
  const double f = static_cast<double>(within) / static_cast<double>(total);
  std::printf("  adaptive rel_error %.2g: true error within target for %.4f of %llu pixel-seed pairs\n", target, f,
              static_cast<unsigned long long>(total));
  EXPECT_GE(f, 0.90);
}

json cornell_qmc_spec() {
  json m = {{"white", diffuse(0.75)}, {"red", {{"type", "diffuse"}, {"albedo", {0.7, 0.1, 0.1}}}},
            {"lamp", emitter(12.0)},
            {"gloss", {{"type", "phong"}, {"reflectance", {0.8, 0.8, 0.8}}, {"exponent", 30}}}};
  json shapes = json::array({
      {{"type", "quad"}, {"corner", {-1, 0, -1}}, {"edge_u", {0, 0, 2}}, {"edge_v", {2, 0, 0}}, {"material", "white"}},
      {{"type", "quad"}, {"corner", {-1, 0, -1}}, {"edge_u", {2, 0, 0}}, {"edge_v", {0, 2, 0}}, {"material", "white"}},
      {{"type", "quad"}, {"corner", {-1, 0, -1}}, {"edge_u", {0, 2, 0}}, {"edge_v", {0, 0, 2}}, {"material", "red"}},
      {{"type", "quad"}, {"corner", {-0.25, 1.99, -0.25}}, {"edge_u", {0.5, 0, 0}}, {"edge_v", {0, 0, 0.5}}, {"material", "lamp"}},
      {{"type", "sphere"}, {"center", {-0.4, 0.35, -0.3}}, {"radius", 0.35}, {"material", "gloss"}},
  });
  return {{"kind", "lighting"},
          {"seed", 9},
          {"sampler", "sobol"},
          {"scene", {{"camera", {{"position", {0, 1, 3.5}}, {"look_at", {0, 1, 0}}, {"fov_deg", 40}, {"resolution", {24, 20}}}},
                     {"materials", m},
                     {"shapes", shapes}}},
          {"query", {{"type", "image"}, {"max_depth", 4}, {"russian_roulette", true}, {"tile_size", 8}}},
          {"estimators", {"mis"}},
          {"stop", {{"max_samples", 40}}}};
}

TEST(QmcDeterminism, ImageBitIdenticalOneVsTwoThreads) {
  const JobRun a = run_spec(cornell_qmc_spec(), 1);
  const JobRun b = run_spec(cornell_qmc_spec(), 2);
  EXPECT_EQ(a.runner->state().samples, 40u);
  EXPECT_EQ(a.runner->state().sums.size(), 24u * 20u * 3u * kDefaultImageReplicates);
  EXPECT_EQ(differing_channels(a, b), 0u);
  EXPECT_TRUE(a.runner->state().counters == b.runner->state().counters);
}

// Runs `runner` on one thread and stops it after `passes` passes (a checkpoint's moment).
void run_passes(JobRunner& runner, uint64_t passes) {
  std::atomic<bool> stop{false};
  LocalRunOptions o;
  o.threads = 1;
  o.cancel = &stop;
  o.on_pass = [&](const JobRunner& r) {
    if (r.state().passes == passes) stop = true;
  };
  run_local(runner, o);
}

TEST(QmcDeterminism, ResumeFromCheckpointIsBitIdentical) {
  for (const json& spec : {cornell_qmc_spec(), point_query_spec(3, 4096, {"mis", "light_area"}, json::object())}) {
    const JobRun whole = run_spec(spec, 2);
    auto job = compile_lighting_job(spec, JobLimits{});
    JobRunner first(job->kernel(), job->stop_rule(), JobCaps{});
    run_passes(first, 2);
    ASSERT_EQ(first.state().passes, 2u);
    ASSERT_LT(first.state().samples, whole.runner->state().samples);
    JobRunner resumed(job->kernel(), job->stop_rule(), JobCaps{}, decode_checkpoint(encode_checkpoint(first.state())));
    run_local(resumed, 2);
    EXPECT_EQ(resumed.state().samples, whole.runner->state().samples);
    EXPECT_TRUE(resumed.state().channels == whole.runner->state().channels);
    EXPECT_EQ(differing_sums(resumed.state().sums, whole.runner->state().sums), 0u);
    EXPECT_TRUE(resumed.state().counters == whole.runner->state().counters);
  }
}

// Results version 2 and earlier kept a tally (n, mean, M2) per replicate channel of an
// image; this build keeps a sum. Such a checkpoint resumes: each sum becomes mean x n,
// and the job finishes with the image of an uninterrupted run up to that rounding. A
// state that fits neither layout is refused naming both sizes and the version.
TEST(QmcDeterminism, ImageCheckpointOfTheTallyLayoutResumes) {
  const json spec = cornell_qmc_spec();
  const JobRun whole = run_spec(spec, 2);
  auto job = compile_lighting_job(spec, JobLimits{});
  const auto* img = dynamic_cast<const ImageKernel*>(job->image());
  ASSERT_NE(img, nullptr);
  const uint32_t k = img->replicates();
  JobRunner first(job->kernel(), job->stop_rule(), JobCaps{});
  run_passes(first, 3);
  ASSERT_EQ(first.state().passes, 3u);
  const JobState& now = first.state();
  ASSERT_EQ(now.sums.size(), img->sum_count());
  // The same state in the old layout: replicate r of a pixel of tile t held
  // partition_samples[t] / K samples.
  JobState old = now;
  old.sums.clear();
  old.channels.resize(now.sums.size());
  const int ts = img->tile_size(), tiles_x = (img->width() + ts - 1) / ts;
  for (int y = 0; y < img->height(); ++y) {
    for (int x = 0; x < img->width(); ++x) {
      const uint64_t per = now.partition_samples[static_cast<size_t>((y / ts) * tiles_x + x / ts)] / k;
      ASSERT_GT(per, 0u);
      for (size_t c = img->pixel_channel(x, y), e = c + 3 * k; c < e; ++c) {
        old.channels[c] = Tally{per, static_cast<double>(now.sums[c]) / static_cast<double>(per), 0.0};
      }
    }
  }
  old.results_version = 2;
  JobRunner resumed(job->kernel(), job->stop_rule(), JobCaps{}, decode_checkpoint(encode_checkpoint(old)));
  EXPECT_TRUE(resumed.state().channels.empty());
  ASSERT_EQ(resumed.state().sums.size(), now.sums.size());
  for (size_t c = 0; c < now.sums.size(); ++c) {
    ASSERT_EQ(resumed.state().sums[c], now.sums[c]) << c;  // mean x n rounds back to the float
  }
  run_local(resumed, 2);
  ASSERT_EQ(resumed.state().samples, whole.runner->state().samples);
  const JobState& a = resumed.state();
  const JobState& b = whole.runner->state();
  for (int y = 0; y < img->height(); ++y) {
    for (int x = 0; x < img->width(); ++x) {
      for (size_t c = 0; c < 3; ++c) {
        const ReplicatedEstimate ea = img->pixel_estimate(a, img->pixel_channel(x, y), c);
        const ReplicatedEstimate eb = img->pixel_estimate(b, img->pixel_channel(x, y), c);
        ASSERT_EQ(ea.n, eb.n);
        ASSERT_NEAR(ea.mean, eb.mean, 1e-12 * (std::fabs(eb.mean) + 1e-9)) << x << " " << y;
        ASSERT_NEAR(ea.std_error, eb.std_error, 1e-9 * (eb.std_error + 1e-9)) << x << " " << y;
      }
    }
  }
  // Neither layout: refused, naming the sizes and the version that wrote it.
  JobState wrong = now;
  wrong.sums.pop_back();
  wrong.results_version = 2;
  try {
    JobRunner r(job->kernel(), job->stop_rule(), JobCaps{}, wrong);
    FAIL() << "a state of the wrong size was resumed";
  } catch (const std::invalid_argument& e) {
    EXPECT_EQ(std::string(e.what()),
              fmt::format("checkpoint does not match the job: 0 channels / {} sums / {} partitions, expected 0 / {} / {} "
                          "(it was written by results version 2; this build is version {})",
                          now.sums.size() - 1, now.partition_samples.size(), now.sums.size(),
                          now.partition_samples.size(), kResultsVersion));
  }
}

TEST(QmcSpec, SamplerIsCheckedAndReported) {
  json spec = cornell_qmc_spec();
  spec["sampler"] = "halton";
  try {
    compile_lighting_job(spec, JobLimits{});
    FAIL() << "expected a SpecError";
  } catch (const SpecError& e) {
    EXPECT_EQ(e.pointer(), "/sampler");
  }
  spec["sampler"] = "independent";
  spec["replicates"] = 4;
  try {
    compile_lighting_job(spec, JobLimits{});
    FAIL() << "expected a SpecError";
  } catch (const SpecError& e) {
    EXPECT_EQ(e.pointer(), "/replicates");
  }
  spec["sampler"] = "sobol";
  spec["replicates"] = 1;
  EXPECT_THROW(compile_lighting_job(spec, JobLimits{}), SpecError);
  spec["replicates"] = 4;
  const auto job = compile_lighting_job(spec, JobLimits{});
  EXPECT_EQ(plan_json(*job)["sampler"]["type"], "sobol");
  EXPECT_EQ(plan_json(*job)["sampler"]["replicates"], 4);
  EXPECT_EQ(job->kernel()->sum_count(), 24u * 20u * 3u * 4u);
  // The default is sobol with 4 replicates for an image, 8 for points.
  spec.erase("sampler");
  spec.erase("replicates");
  EXPECT_EQ(plan_json(*compile_lighting_job(spec, JobLimits{}))["sampler"]["replicates"], 4);
  EXPECT_EQ(kDefaultImageReplicates, 4u);
  const json points = point_query_spec(4, 1024, {"light_area"}, json::object());
  EXPECT_EQ(plan_json(*compile_lighting_job(points, JobLimits{}))["sampler"]["replicates"], 8);
  EXPECT_EQ(kDefaultPointReplicates, 8u);
}

// A spec stored by an older build reads as that build read it (job_kinds.hpp,
// spec_as_of): up to results version 4 a sobol image job without "replicates" had 8;
// anything else is left as it is (point queries have 8 in both).
TEST(QmcSpec, SpecAsOfAnOlderVersionWritesInTheReplicatesItHad) {
  const json spec = {{"kind", "lighting"}, {"seed", 1}, {"query", {{"type", "image"}}}};
  for (const uint32_t v : {0u, 1u, 4u}) EXPECT_EQ(spec_as_of(spec, v).at("replicates"), 8) << v;
  EXPECT_EQ(spec_as_of(spec, kResultsVersion), spec);
  json sobol = spec;
  sobol["sampler"] = "sobol";
  EXPECT_EQ(spec_as_of(sobol, 4).at("replicates"), 8);
  json given = spec;
  given["replicates"] = 16;
  EXPECT_EQ(spec_as_of(given, 4), given);
  json independent = spec;
  independent["sampler"] = "independent";
  EXPECT_EQ(spec_as_of(independent, 4), independent);
  const json points = point_query_spec(4, 1024, {"light_area"}, json::object());
  EXPECT_EQ(spec_as_of(points, 4), points);
  json odd = spec;
  odd["query"] = "image";  // not an object: the spec reader names it, spec_as_of leaves it
  EXPECT_EQ(spec_as_of(odd, 4), odd);
  const json integral = {{"kind", "integration"}, {"seed", 1}};
  EXPECT_EQ(spec_as_of(integral, 4), integral);
  EXPECT_EQ(spec_as_of(json("not an object"), 4), json("not an object"));
  json image = image_spec(8, 8, 1, "mis", {{"max_samples", 16}});
  EXPECT_EQ(plan_json(*compile_job(spec_as_of(image, 4), JobLimits{}))["sampler"]["replicates"], 8);
  EXPECT_EQ(plan_json(*compile_job(image, JobLimits{}))["sampler"]["replicates"], 4);
}

TEST(QmcSpec, PointResultsReportTheVarianceOfTheEstimate) {
  // "variance" = n se^2 and the interval = mean +- t_{K-1} se, from the replicates.
  const JobRun r = run_spec(point_query_spec(4, 1024, {"light_area"}, json::object()));
  const json res = kind_result_json(*r.job, *r.runner);
  const auto& pk = dynamic_cast<const PointKernel&>(r.runner->kernel());
  const ReplicatedEstimate x = pk.estimate(r.runner->state(), 0, 0, 0);
  const json& e = res["points"][0]["estimators"]["light_area"];
  EXPECT_EQ(e["samples"], 1024);
  EXPECT_DOUBLE_EQ(e["std_error"][0].get<double>(), x.std_error);
  EXPECT_DOUBLE_EQ(e["variance"][0].get<double>(), 1024 * x.std_error * x.std_error);
  EXPECT_NEAR(e["ci_hi"][0].get<double>() - e["mean"][0].get<double>(),
              critical_value(0.95, kDefaultPointReplicates) * x.std_error, 1e-15);
}

}  // namespace
}  // namespace tally::test
