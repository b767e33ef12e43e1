// (c) The unit disk: E = integral over the unit disk of x^2 + y^2 = pi/2, estimated
// with five ways of placing points: uniform in the bounding box (indicator), rejection,
// sqrt(xi) polar, concentric, and the lecture's WRONG r = xi polar. The first, second
// and fourth are the product's estimators; the two polar maps are tiny kernels here
// (the wrong one must never be in the product). All five run through JobRunner.
#include <fmt/format.h>

#include <cmath>
#include <numbers>

#include "bench/study/study_support.hpp"
#include "common/engine/pass_loop.hpp"
#include "common/rng/counter_rng.hpp"
#include "common/sampling/disk.hpp"

namespace tally::study {

namespace {

constexpr double kPi = std::numbers::pi;

// pi * f(p) with p from a polar map of two uniforms; the estimator assumes p is uniform
// on the disk (pdf 1/pi). With r = xi that assumption is false: the pdf is 1/(2 pi r).
class PolarDiskKernel final : public Kernel {
 public:
  PolarDiskKernel(bool wrong, uint64_t seed) : wrong_(wrong), key_(stream_key(seed, 0)) {}
  size_t channel_count() const override { return 1; }
  std::span<const std::string_view> counter_names() const override {
    static constexpr std::string_view kNames[] = {"evaluations"};
    return kNames;
  }
  void run_block(const Block& b, BlockResult& out) const override {
    std::vector<double> v(b.sample_count);
    for (uint64_t i = 0; i < b.sample_count; ++i) {
      const SampleRng rng(key_, b.first_sample + i);
      const Vec2 p = point(Vec2{rng.open_uniform(0), rng.open_uniform(1)});
      v[i] = kPi * (p.x * p.x + p.y * p.y);
      out.tail.offer(std::fabs(v[i]));
    }
    out.counters.add(0, b.sample_count);  // "evaluations"
    out.tallies.assign(1, Tally::from_batch(v.data(), v.size()));
  }
  Vec2 point(Vec2 u) const {
    if (!wrong_) return sample_uniform_disk_polar(u);
    const double r = u.x, theta = 2 * kPi * u.y;  // the lecture's WRONG map
    return {r * std::cos(theta), r * std::sin(theta)};
  }

 private:
  bool wrong_;
  uint64_t key_;
};

json disk_spec(const std::string& method, uint64_t N, uint64_t seed) {
  json spec = {{"kind", "integrate"}, {"seed", seed}, {"stop", {{"max_samples", N}}}};
  if (method == "box_uniform") {
    spec["integrand"] = {{"expression", "x*x + y*y < 1 ? x*x + y*y : 0"}};
    spec["domain"] = {{"type", "box"}, {"lower", {-1, -1}}, {"upper", {1, 1}}};
    spec["estimator"] = {{"type", "uniform"}};
  } else {
    spec["integrand"] = {{"expression", "x*x + y*y"}};
    spec["domain"] = {{"type", "disk"}};
    spec["estimator"] = {{"type", method == "rejection" ? "rejection" : "uniform"}};
  }
  return spec;
}

}  // namespace

void run_disk_study(const Options& o) {
  const double exact = kPi / 2;
  Csv csv(o.out / "disk.csv",
          {"method", "N", "seeds", "mean", "rmse", "mean_reported_se", "seconds", "evaluations", "exact"});
  const int seeds = o.quick ? 4 : 16;
  const int max_log2 = o.quick ? 14 : 20;
  const std::vector<std::string> methods = {"box_uniform", "rejection", "polar_sqrt", "concentric", "wrong_polar"};
  for (const std::string& m : methods) {
    for (int k = 6; k <= max_log2; k += 2) {
      const uint64_t N = uint64_t{1} << k;
      Tally est;
      double sq = 0, se = 0, secs = 0, evals = 0;
      for (int s = 1; s <= seeds; ++s) {
        JobRun r;
        if (m == "polar_sqrt" || m == "wrong_polar") {
          StopRule rule;
          rule.max_samples = N;
          r = run_kernel(std::make_shared<PolarDiskKernel>(m == "wrong_polar", static_cast<uint64_t>(s)), rule,
                         o.threads);
        } else {
          r = run_spec(disk_spec(m == "concentric" ? "disk" : m, N, static_cast<uint64_t>(s)), o.threads);
        }
        const Estimate e = r.runner->estimate(0);
        est.add(e.mean);
        sq += (e.mean - exact) * (e.mean - exact);
        se += e.std_error;
        secs += r.compute_seconds();
        evals += static_cast<double>(r.evaluations());
      }
      csv.row({m, N, seeds, est.mean, std::sqrt(sq / seeds), se / seeds, secs / seeds, evals / seeds, exact});
    }
    log("disk " + m + " done");
  }
  // 1500 points of each map for the scatter plot.
  Csv pts(o.out / "disk_points.csv", {"method", "x", "y"});
  const uint64_t key = stream_key(2016, 0);
  const PolarDiskKernel polar(false, 1), wrong(true, 1);
  for (uint64_t i = 0; i < 1500; ++i) {
    SampleRng rng(key, i);
    const Vec2 u{rng.open_uniform(0), rng.open_uniform(1)};
    const Vec2 a = polar.point(u), b = wrong.point(u), c = sample_uniform_disk_concentric(u);
    pts.row({"polar_sqrt", a.x, a.y});
    pts.row({"wrong_polar", b.x, b.y});
    pts.row({"concentric", c.x, c.y});
    pts.row({"box_uniform", 2 * u.x - 1, 2 * u.y - 1});
    SampleRng rr(stream_key(2016, 1), i);
    RejectionStats st;
    if (auto q = sample_uniform_disk_rejection(rr, 1000, st)) pts.row({"rejection", q->x, q->y});
  }
}

}  // namespace tally::study
