#include "common/lighting/lighting_job.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <limits>
#include <numeric>

namespace tally {

LightingJob::LightingJob(std::shared_ptr<const PointKernel> points, std::shared_ptr<const ImageKernel> image,
                         StopRule stop, uint64_t seed, LightingPlan plan)
    : points_(std::move(points)), image_(std::move(image)), stop_(stop), seed_(seed), plan_(std::move(plan)) {
  if (points_) {
    kernel_ = points_;
  } else {
    kernel_ = image_;
  }
}

LightingResult LightingJob::result(const JobRunner& runner) const {
  LightingResult r;
  const JobState& st = runner.state();
  const double conf = runner.rule().confidence;
  if (points_) {
    std::vector<PointResult> pts;
    for (size_t k = 0; k < points_->points().size(); ++k) {
      PointResult pr;
      pr.index = k;
      pr.p = points_->points()[k].world_p;
      for (size_t e = 0; e < points_->strategies().size(); ++e) {
        PointEstimate o;
        o.estimator = plan_.estimators[e];
        double var_sum = 0;
        for (int c = 0; c < 3; ++c) {
          // "variance" is n se^2, the variance of the estimate per sample: the sample
          // variance for independent samples, the replicates' spread under RQMC.
          const ReplicatedEstimate t = points_->estimate(st, e, k, c);
          const double h = t.has_error() ? t.half_width(conf) : 0.0;
          o.mean[c] = t.mean;
          o.std_error[c] = t.has_error() ? t.std_error : 0.0;
          o.variance[c] = t.effective_variance();
          o.ci_lo[c] = t.mean - h;
          o.ci_hi[c] = t.mean + h;
          var_sum += t.effective_variance();
          o.samples = t.n;
        }
        o.seconds_per_sample = points_->seconds_per_sample(e);
        // Efficiency 1 / (sigma^2 t): sigma^2 the mean of the RGB variances of the estimate.
        const double sigma2 = var_sum / 3.0;
        if (sigma2 > 0 && o.seconds_per_sample > 0) o.efficiency = 1.0 / (sigma2 * o.seconds_per_sample);
        pr.estimates.push_back(std::move(o));
      }
      pts.push_back(std::move(pr));
    }
    r.points = std::move(pts);
  }
  if (image_) {
    uint64_t lo = std::numeric_limits<uint64_t>::max(), hi = 0;
    for (uint64_t s : st.partition_samples) {
      lo = std::min(lo, s);
      hi = std::max(hi, s);
    }
    const ErrorSummary e = runner.error();
    r.image = LightingImageResult{image_->width(), image_->height(), image_->tile_size(), image_->tile_count(),
                                  lo, hi, e.abs_error, e.rel_error};
  }
  return r;
}

std::string LightingJob::summary_line(const JobRunner& runner) const {
  if (image_) {
    const ErrorSummary e = runner.error();
    return fmt::format("image {}x{}, {} spp, mean relative error {:.3g}", image_->width(), image_->height(),
                       runner.state().samples, e.rel_error);
  }
  // One line per (point, estimator), estimators side by side on common random numbers,
  // in the order of their names (as the JSON result lists them).
  const LightingResult res = result(runner);
  const std::vector<PointResult>& pts = *res.points;
  std::string out;
  for (size_t p = 0; p < pts.size() && p < 8; ++p) {
    std::vector<const PointEstimate*> by_name;
    for (const PointEstimate& e : pts[p].estimates) by_name.push_back(&e);
    std::sort(by_name.begin(), by_name.end(),
              [](const PointEstimate* a, const PointEstimate* b) { return a->estimator < b->estimator; });
    for (const PointEstimate* e : by_name) {
      const auto& m = e->mean;
      const auto& se = e->std_error;
      out += fmt::format("{}L_o(point {}, {:<18}) = ({:.6g}, {:.6g}, {:.6g}) ± ({:.3g}, {:.3g}, {:.3g})  efficiency 1/(σ²t) {:.3g}",
                         out.empty() ? "" : "\n", p, e->estimator, m[0], m[1], m[2], se[0], se[1], se[2],
                         e->efficiency.value_or(0.0));
    }
  }
  if (pts.size() > 8) out += fmt::format("\n... {} more points (see --json)", pts.size() - 8);
  return out;
}

}  // namespace tally
