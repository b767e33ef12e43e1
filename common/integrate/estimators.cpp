#include "common/integrate/estimators.hpp"

#include <algorithm>
#include <limits>
#include <array>
#include <cmath>
#include <fmt/format.h>
#include <numbers>
#include <span>

#include "common/engine/channel_summary.hpp"
#include "common/engine/block_abandon.hpp"
#include "common/engine/job_state.hpp"
#include "common/integrate/integration_counters.hpp"
#include "common/rng/counter_rng.hpp"
#include "common/sampling/piecewise_constant.hpp"
#include "common/sampling/qmc.hpp"
#include "common/sampling/sphere.hpp"

namespace tally {

namespace {

constexpr size_t kB = kIntegrandBatch;
// Components of a vector integrand a sweep evaluates at once (256 x kB doubles a thread).
constexpr size_t kComponentChunk = 256;

// Per-thread structure-of-arrays buffers for one batch.
struct Scratch {
  std::vector<double> u, x, f, pdf;
  std::vector<uint64_t> base = std::vector<uint64_t>(kIntegrandBatch);
  std::vector<const double*> u_ptr, x_cptr;
  std::vector<double*> x_ptr;

  void ensure(size_t uniforms, size_t dims) {
    if (u.size() < uniforms * kB) u.resize(uniforms * kB);
    if (x.size() < dims * kB) x.resize(dims * kB);
    f.resize(kB);
    pdf.resize(kB);
    u_ptr.resize(uniforms);
    x_ptr.resize(dims);
    x_cptr.resize(dims);
    for (size_t k = 0; k < uniforms; ++k) u_ptr[k] = u.data() + k * kB;
    for (size_t k = 0; k < dims; ++k) {
      x_ptr[k] = x.data() + k * kB;
      x_cptr[k] = x_ptr[k];
    }
  }
  double* urow(size_t k) { return u.data() + k * kB; }
};

Scratch& scratch() {
  thread_local Scratch s;
  return s;
}

// True if every value is finite (x * 0 is NaN exactly for NaN and +-Inf).
bool all_finite(const double* v, size_t n) {
  // Four independent accumulators: no serial add chain in the hot loop.
  double acc[4] = {0.0, 0.0, 0.0, 0.0};
  size_t i = 0;
  for (; i + 4 <= n; i += 4) {
    for (size_t k = 0; k < 4; ++k) acc[k] += v[i + k] * 0.0;
  }
  for (; i < n; ++i) acc[0] += v[i] * 0.0;
  return (acc[0] + acc[1]) + (acc[2] + acc[3]) == 0.0;
}

// `what`: the sample's description when it is not the integrand's value itself (an
// importance weight f/p); empty: "the integrand is NaN / infinite at ...".
void record_fault(BlockResult& out, uint64_t sample_index, double value, const Scratch& s, size_t i,
                  size_t dims, const std::string& what = {}) {
  if (out.fault) return;
  SampleFault f;
  f.sample_index = sample_index;
  f.value = value;
  for (size_t k = 0; k < dims; ++k) f.point.push_back(s.x[k * kB + i]);
  std::string where;
  for (size_t k = 0; k < dims; ++k) where += fmt::format("{}x{} = {:.17g}", k ? ", " : "", k, f.point[k]);
  f.message = what.empty() ? fmt::format("the integrand is {} at {} (sample {})", std::isnan(value) ? "NaN" : "infinite",
                                         where, sample_index)
                           : fmt::format("{} at {} (sample {})", what, where, sample_index);
  out.fault = std::move(f);
}

// Common block driver: estimators fill `values` for samples [first, first + count)
// and return how many they wrote (rejection may drop samples; a fault stops early).
class IntegrationKernelBase : public Kernel {
 public:
  explicit IntegrationKernelBase(IntegrationProblem p)
      : p_(std::move(p)), key_(stream_key(p_.seed, 0)) {}
  size_t channel_count() const override { return 1; }
  bool plans_from_counts() const override { return true; }  // fixed pass sizes, no pass input
  std::span<const std::string_view> counter_names() const override { return integration_counter_names(); }
  std::vector<std::string> warnings(const JobState& st) const override { return integration_counter_warnings(st); }
  PassSchedule schedule() const override {
    const uint64_t per = std::max<uint64_t>(1, evaluations_per_sample());
    PassSchedule s;
    s.block_samples = std::max<uint64_t>(1, 4096 / per);
    s.first_pass_samples = std::max<uint64_t>(4 * s.block_samples, 16384 / per);
    // 2^24 evaluations: ~40-80 ms for fast integrands, so progress events, checkpoints and
    // scheduler commits stay a small fraction of the work.
    s.max_pass_samples = std::max<uint64_t>(s.first_pass_samples, (uint64_t{1} << 24) / per);
    // A block of a cheap integrand is ~20 us of work: its results merge 16 at a time
    // (~0.3 ms), so a cluster worker sends one result per 16 blocks, and a full pass
    // (4096 blocks) is still 256 groups to spread over workers.
    s.group_blocks = 16;
    return s;
  }
  void run_block(const Block& b, BlockResult& out) const override {
    thread_local std::vector<double> values;
    values.resize(b.sample_count);
    const size_t n = fill(b.first_sample, b.sample_count, values.data(), out);
    double threshold = out.tail.threshold();
    for (size_t i = 0; i < n; ++i) {
      const double m = std::fabs(values[i]);
      if (m > threshold) {
        out.tail.offer(m);
        threshold = out.tail.threshold();
      }
    }
    out.tallies.assign(1, Tally::from_batch(values.data(), n));
  }
  virtual uint64_t evaluations_per_sample() const { return 1; }

 protected:
  virtual size_t fill(uint64_t first, uint64_t count, double* values, BlockResult& out) const = 0;

  // Uniforms of samples [first, first + n) into the scratch rows, open interval (0,1).
  // Structure-of-arrays loops over the batch, one dimension at a time, so the
  // compiler can pipeline (and with AVX2, vectorize) the mixer.
  void draw_uniforms(Scratch& s, uint64_t first, size_t n, uint32_t uniforms) const {
    fill_bases(s, first, n);
    for (uint32_t k = 0; k < uniforms; ++k) fill_row(s.urow(k), s.base.data(), n, k, 0x1.0p-54, 0x1.0p-53);
  }
  // Uniform points of a box straight into the coordinate rows: x = lo + w * u with
  // u = (m + 1/2) 2^-53 folded into one multiply-add per coordinate.
  void draw_box_points(Scratch& s, uint64_t first, size_t n, const Domain& box) const {
    fill_bases(s, first, n);
    for (size_t k = 0; k < box.dimensions(); ++k) {
      const double lo = box.lower()[k], w = box.upper()[k] - box.lower()[k];
      fill_row(s.x_ptr[k], s.base.data(), n, static_cast<uint32_t>(k), lo + w * 0x1.0p-54, w * 0x1.0p-53);
    }
  }
  void fill_bases(Scratch& s, uint64_t first, size_t n) const {
    uint64_t* base = s.base.data();
    for (size_t i = 0; i < n; ++i) base[i] = SampleRng::sample_base(key_, first + i);
  }
  static void fill_row(double* row, const uint64_t* base, size_t n, uint32_t k, double offset, double scale) {
    for (size_t i = 0; i < n; ++i) {
      const auto m = static_cast<int64_t>(SampleRng::bits_at(base[i], k) >> 11);
      row[i] = offset + scale * static_cast<double>(m);
    }
  }

  // Checks a batch of values; on a non-finite one records the fault and returns its
  // position, else n.
  size_t check(double* v, size_t n, uint64_t first, const Scratch& s, BlockResult& out) const {
    if (all_finite(v, n)) return n;
    for (size_t i = 0; i < n; ++i) {
      if (!std::isfinite(v[i])) {
        out.counters.add(IntegrationCounter::nonfinite);
        record_fault(out, first + i, v[i], s, i, p_.domain->dimensions());
        return i;
      }
    }
    return n;
  }

  IntegrationProblem p_;
  uint64_t key_;
};

// Point-by-point estimators share one batch loop: draw a batch of points, evaluate
// the integrand, turn values into samples (the subclass's weight), check them.
class PointwiseKernelBase : public IntegrationKernelBase {
 public:
  using IntegrationKernelBase::IntegrationKernelBase;

 protected:
  // Fill the coordinate rows (and pdf, for importance sampling) of n points.
  virtual void draw(Scratch& s, uint64_t first, size_t n) const = 0;
  // f values -> samples, in place (samples first ... first + n - 1).
  virtual void weigh(const Scratch& s, double* v, size_t n, uint64_t first, BlockResult& out) const = 0;

  size_t fill(uint64_t first, uint64_t count, double* values, BlockResult& out) const override {
    Scratch& s = scratch();
    s.ensure(p_.domain->uniforms(), p_.domain->dimensions());
    for (uint64_t off = 0; off < count; off += kB) {
      const size_t n = static_cast<size_t>(std::min<uint64_t>(kB, count - off));
      draw(s, first + off, n);
      double* v = values + off;
      p_.integrand->evaluate_batch(s.x_cptr.data(), n, v);
      weigh(s, v, n, first + off, out);
      out.counters.add(IntegrationCounter::evaluations, n);
      const size_t ok = check(v, n, first + off, s, out);
      if (ok < n) return static_cast<size_t>(off) + ok;
    }
    return static_cast<size_t>(count);
  }
};

class UniformKernel final : public PointwiseKernelBase {
 public:
  using PointwiseKernelBase::PointwiseKernelBase;

 protected:
  void draw(Scratch& s, uint64_t first, size_t n) const override {
    const Domain& D = *p_.domain;
    if (D.is_box()) {
      draw_box_points(s, first, n, D);
    } else {
      draw_uniforms(s, first, n, D.uniforms());
      D.map_uniform(s.u_ptr.data(), n, s.x_ptr.data());
    }
  }
  void weigh(const Scratch&, double* v, size_t n, uint64_t, BlockResult&) const override {
    const double measure = p_.domain->measure();
    for (size_t i = 0; i < n; ++i) v[i] *= measure;
  }
};

// Importance sampling: subclasses map uniforms to x and fill pdf.
class ImportanceKernelBase : public PointwiseKernelBase {
 public:
  using PointwiseKernelBase::PointwiseKernelBase;

 protected:
  virtual void map(Scratch& s, size_t n) const = 0;
  void draw(Scratch& s, uint64_t first, size_t n) const override {
    draw_uniforms(s, first, n, p_.domain->uniforms());
    map(s, n);
  }
  void weigh(const Scratch& s, double* v, size_t n, uint64_t first, BlockResult& out) const override {
    const double measure = p_.domain->measure();
    bool faulted = false;  // check() reports the batch's first non-finite sample
    for (size_t i = 0; i < n; ++i) {
      const double pdf = s.pdf[i], f = v[i];
      // pdf -> 0 only where the density vanishes; weight 0 there, never Inf.
      v[i] = pdf > 0.0 ? f / pdf : 0.0;
      out.weights.add(pdf > 0.0 ? 1.0 / (pdf * measure) : 0.0);
      if (faulted || std::isfinite(v[i])) continue;
      faulted = true;
      if (std::isfinite(f) || (std::isinf(f) && std::isinf(pdf))) {
        // It is the weight that is not finite, not (only) the integrand: say so; check()
        // counts it and keeps this message.
        record_fault(out, first + i, v[i], s, i, p_.domain->dimensions(),
                     std::isfinite(f) ? fmt::format("the weight f/p = {:.17g} / {:.17g} is not finite (the density "
                                                    "vanishes or overflows there, the integrand is finite)", f, pdf)
                                      : fmt::format("the weight f/p = {} / {} is NaN (the integrand and the density both "
                                                    "overflow there)", f, pdf));
      }
    }
  }
};

class PowerImportanceKernel final : public ImportanceKernelBase {
 public:
  PowerImportanceKernel(IntegrationProblem p, PowerDensity d)
      : ImportanceKernelBase(std::move(p)), d_(std::move(d)) {}

 protected:
  void map(Scratch& s, size_t n) const override {
    const Domain& D = *p_.domain;
    std::fill(s.pdf.begin(), s.pdf.begin() + static_cast<std::ptrdiff_t>(n), 1.0);
    for (size_t k = 0; k < D.dimensions(); ++k) {
      const double lo = D.lower()[k], w = D.upper()[k] - D.lower()[k];
      const double e = d_.exponents[k];
      const double inv = 1.0 / (e + 1.0);
      const double hi = D.upper()[k];
      constexpr double kMinNormal = std::numeric_limits<double>::min();
      const double min_dx = std::max({std::nextafter(lo, hi) - lo, kMinNormal, kMinNormal * w});
      for (size_t i = 0; i < n; ++i) {
        // Inverse CDF of (e+1) t^e on (0,1): t = u^(1/(e+1)).
        double t = std::pow(s.urow(k)[i], inv);
        double x = lo + t * w;
        // For e near -1 the draw can lie below the first double after lo (t
        // underflows to 0 when e <= -0.99), for large e it can round up to hi: keep x
        // in the open interval, with the density there. Near lo, x - lo and t stay
        // normal doubles (>= DBL_MIN): below that (x0 = 4.94e-324 for e = -0.99 on
        // [0, 1]) t^e and a singular integrand like x0^e both overflow, and the weight
        // f/p is inf/inf. From DBL_MIN up, f/p is finite wherever f is proportional to p.
        if (!(x - lo >= min_dx) || !(x < hi)) {
          x = x < hi ? lo + min_dx : std::nextafter(hi, lo);
          t = (x - lo) / w;
        }
        s.x_ptr[k][i] = x;
        s.pdf[i] *= (e + 1.0) * std::pow(t, e) / w;
      }
    }
  }

 private:
  PowerDensity d_;
};

class TabulatedImportanceKernel final : public ImportanceKernelBase {
 public:
  TabulatedImportanceKernel(IntegrationProblem p, TabulatedDensity d)
      : ImportanceKernelBase(std::move(p)) {
    const Domain& D = *p_.domain;
    if (d.nv == 0) {
      d1_.emplace(d.values, D.lower()[0], D.upper()[0]);
    } else {
      Box2 box;
      box.lo = Vec2{D.lower()[0], D.lower()[1]};
      box.hi = Vec2{D.upper()[0], D.upper()[1]};
      d2_.emplace(d.values, d.nu, d.nv, box);
    }
  }

 protected:
  void map(Scratch& s, size_t n) const override {
    for (size_t i = 0; i < n; ++i) {
      if (d1_) {
        const auto smp = d1_->sample(s.urow(0)[i]);
        s.x_ptr[0][i] = smp.x;
        s.pdf[i] = smp.pdf;
      } else {
        const auto smp = d2_->sample(Vec2{s.urow(0)[i], s.urow(1)[i]});
        s.x_ptr[0][i] = smp.point.x;
        s.x_ptr[1][i] = smp.point.y;
        s.pdf[i] = smp.pdf;
      }
    }
  }

 private:
  std::optional<PiecewiseConstant1D> d1_;
  std::optional<PiecewiseConstant2D> d2_;
};

class CosineImportanceKernel final : public ImportanceKernelBase {
 public:
  CosineImportanceKernel(IntegrationProblem p) : ImportanceKernelBase(std::move(p)) {
    const Domain& D = *p_.domain;
    for (int k = 0; k < 3; ++k) center_[k] = 0.5 * (D.lower()[static_cast<size_t>(k)] + D.upper()[static_cast<size_t>(k)]);
    radius_ = 0.5 * (D.upper()[0] - D.lower()[0]);
  }

 protected:
  void map(Scratch& s, size_t n) const override {
    const double area_scale = radius_ * radius_;
    for (size_t i = 0; i < n; ++i) {
      const Vec3 w = sample_cosine_hemisphere(Vec2{s.urow(0)[i], s.urow(1)[i]});
      s.x_ptr[0][i] = center_[0] + radius_ * w.x;
      s.x_ptr[1][i] = center_[1] + radius_ * w.y;
      s.x_ptr[2][i] = center_[2] + radius_ * w.z;
      s.pdf[i] = cosine_hemisphere_pdf(w.z) / area_scale;
    }
  }

 private:
  double center_[3] = {0, 0, 0};
  double radius_ = 1.0;
};

// Sweep-based estimators: one sample = the mean over a point set.
class SweepKernelBase : public IntegrationKernelBase {
 public:
  SweepKernelBase(IntegrationProblem p, uint64_t points)
      : IntegrationKernelBase(std::move(p)), points_(points), m_(p_.integrand->components()) {}
  uint64_t evaluations_per_sample() const override { return points_; }

  // A vector integrand: one channel per component (then, with covariance, one per pair
  // a < c holding f_a + f_c). Every component is averaged over the same point sets, so
  // component c is bit-identical to the scalar job of its function with the same seed.
  size_t channel_count() const override { return m_ + (p_.covariance ? m_ * (m_ - 1) / 2 : 0); }
  void run_block(const Block& b, BlockResult& out) const override {
    if (channel_count() == 1) {
      IntegrationKernelBase::run_block(b, out);
      return;
    }
    run_vector_block(b, out);
  }
  ErrorSummary error_summary(const JobState& st, double confidence) const override {
    const std::span<const Tally> all(st.channels);
    return worst_channel_summary(all.first(std::min(m_, all.size())), confidence);
  }
  std::vector<ComponentError> component_errors(const JobState& st, double confidence) const override {
    const std::span<const Tally> all(st.channels);
    return channel_errors(all.first(std::min(m_, all.size())), confidence);
  }

 protected:
  // Fill the scratch uniform rows with points [j0, j0 + n) of sweep `sample`. True if
  // the points carry weights (a transform's Jacobian) in s.pdf, which multiply f.
  virtual bool sweep_uniforms(Scratch& s, uint64_t sample, uint64_t j0, size_t n) const = 0;

  size_t fill(uint64_t first, uint64_t count, double* values, BlockResult& out) const override {
    Scratch& s = scratch();
    const Domain& D = *p_.domain;
    s.ensure(D.uniforms(), D.dimensions());
    const double measure = D.measure();
    for (uint64_t k = 0; k < count; ++k) {
      const uint64_t sample = first + k;
      // Pairwise-style: per-batch sums, then summed in a fixed order.
      double total = 0.0;
      for (uint64_t j0 = 0; j0 < points_; j0 += kB) {
        if (block_abandoned()) return static_cast<size_t>(k);  // dropped (block_abandon.hpp)
        const size_t n = static_cast<size_t>(std::min<uint64_t>(kB, points_ - j0));
        const bool weighted = sweep_uniforms(s, sample, j0, n);
        D.map_uniform(s.u_ptr.data(), n, s.x_ptr.data());
        p_.integrand->evaluate_batch(s.x_cptr.data(), n, s.f.data());
        if (!all_finite(s.f.data(), n)) {
          for (size_t i = 0; i < n; ++i) {
            if (!std::isfinite(s.f[i])) {
              out.counters.add(IntegrationCounter::nonfinite);
              record_fault(out, sample, s.f[i], s, i, D.dimensions());
              return static_cast<size_t>(k);
            }
          }
        }
        double batch = 0.0;
        if (weighted) {
          for (size_t i = 0; i < n; ++i) batch += s.f[i] * s.pdf[i];
        } else {
          for (size_t i = 0; i < n; ++i) batch += s.f[i];
        }
        total += batch;
      }
      out.counters.add(IntegrationCounter::evaluations, points_);
      values[k] = measure * total / static_cast<double>(points_);
    }
    return static_cast<size_t>(count);
  }

  uint64_t points_;

 private:
  // The vector form of fill + IntegrationKernelBase::run_block: per sample (point set),
  // each component's average over the set, summed batch by batch in the scalar order.
  void run_vector_block(const Block& b, BlockResult& out) const {
    const size_t count = static_cast<size_t>(b.sample_count);
    thread_local std::vector<double> vals, fbuf, totals;
    thread_local std::vector<double*> fptr;
    vals.assign(m_ * count, 0.0);
    // kComponentChunk components' batches at a time (evaluated together: what they share
    // runs once): memory does not grow with m.
    const size_t chunk = std::min(m_, kComponentChunk);
    fbuf.resize(chunk * kB);
    fptr.resize(chunk);
    for (size_t i = 0; i < chunk; ++i) fptr[i] = fbuf.data() + i * kB;
    totals.resize(m_);
    Scratch& s = scratch();
    const Domain& D = *p_.domain;
    s.ensure(D.uniforms(), D.dimensions());
    const double measure = D.measure();
    size_t done = count;
    for (size_t k = 0; k < count && done == count; ++k) {
      const uint64_t sample = b.first_sample + k;
      std::fill(totals.begin(), totals.end(), 0.0);
      for (uint64_t j0 = 0; j0 < points_; j0 += kB) {
        if (block_abandoned()) {  // dropped (block_abandon.hpp)
          done = k;
          break;
        }
        const size_t n = static_cast<size_t>(std::min<uint64_t>(kB, points_ - j0));
        const bool weighted = sweep_uniforms(s, sample, j0, n);
        D.map_uniform(s.u_ptr.data(), n, s.x_ptr.data());
        for (size_t c = 0; c < m_ && done == count; ++c) {
          if (c % chunk == 0) {
            p_.integrand->evaluate_component_range(c, std::min(chunk, m_ - c), s.x_cptr.data(), n, fptr.data());
          }
          const double* f = fptr[c % chunk];
          if (!all_finite(f, n)) {
            for (size_t i = 0; i < n; ++i) {
              if (!std::isfinite(f[i])) {
                out.counters.add(IntegrationCounter::nonfinite);
                record_fault(out, sample, f[i], s, i, D.dimensions());
                if (out.fault) out.fault->channel = static_cast<uint32_t>(c);
                break;
              }
            }
            done = k;
            break;
          }
          double batch = 0.0;
          if (weighted) {
            for (size_t i = 0; i < n; ++i) batch += f[i] * s.pdf[i];
          } else {
            for (size_t i = 0; i < n; ++i) batch += f[i];
          }
          totals[c] += batch;
        }
        if (done != count) break;
      }
      if (done != count) break;
      out.counters.add(IntegrationCounter::evaluations, points_);
      for (size_t c = 0; c < m_; ++c) vals[c * count + k] = measure * totals[c] / static_cast<double>(points_);
    }
    out.first_channel = 0;
    out.tallies.assign(channel_count(), Tally{});
    for (size_t c = 0; c < m_; ++c) out.tallies[c] = Tally::from_batch(vals.data() + c * count, done);
    if (p_.covariance) {
      thread_local std::vector<double> pair;
      pair.resize(done);
      size_t ch = m_;
      for (size_t a = 0; a < m_; ++a) {
        for (size_t c = a + 1; c < m_; ++c) {
          for (size_t i = 0; i < done; ++i) pair[i] = vals[a * count + i] + vals[c * count + i];
          out.tallies[ch++] = Tally::from_batch(pair.data(), done);
        }
      }
    }
    double threshold = out.tail.threshold();
    for (size_t i = 0; i < done; ++i) {  // the tail of component 0, as the scalar job's
      const double v = std::fabs(vals[i]);
      if (v > threshold) {
        out.tail.offer(v);
        threshold = out.tail.threshold();
      }
    }
  }

  size_t m_;
};

class StratifiedKernel final : public SweepKernelBase {
 public:
  StratifiedKernel(IntegrationProblem p, uint32_t k, uint32_t s)
      : SweepKernelBase(std::move(p), 1), k_(k), s_(s) {
    points_ = 1;
    for (uint32_t i = 0; i < s_; ++i) points_ *= k_;
  }

 protected:
  bool sweep_uniforms(Scratch& s, uint64_t sample, uint64_t j0, size_t n) const override {
    const uint32_t U = p_.domain->uniforms();
    const double inv_k = 1.0 / static_cast<double>(k_);
    for (size_t i = 0; i < n; ++i) {
      const uint64_t stratum = j0 + i;
      // One counter-based stream per (sweep, stratum): jitter and the free dimensions.
      const SampleRng rng(key_, sample * points_ + stratum);
      uint64_t rest = stratum;
      for (uint32_t d = 0; d < U; ++d) {
        const double jitter = rng.open_uniform(d);
        if (d < s_) {
          const uint64_t cell = rest % k_;
          rest /= k_;
          s.urow(d)[i] = (static_cast<double>(cell) + jitter) * inv_k;
        } else {
          s.urow(d)[i] = jitter;
        }
      }
    }
    return false;
  }

 private:
  uint32_t k_, s_;
};

class QmcKernel final : public SweepKernelBase {
 public:
  QmcKernel(IntegrationProblem p, uint64_t points, bool owen, uint32_t interlacing)
      : SweepKernelBase(std::move(p), points), owen_(owen), interlacing_(interlacing) {}

 protected:
  bool sweep_uniforms(Scratch& s, uint64_t sample, uint64_t j0, size_t n) const override {
    const uint32_t U = p_.domain->uniforms();
    const uint64_t scramble = mix64(key_ ^ mix64(sample + 0x51ed27));
    if (owen_) {
      // Nested uniform (Owen) scramble, hashed bit by bit: the reference scramble,
      // ~20x slower per coordinate than the affine one below.
      for (uint32_t d = 0; d < U; ++d) {
        double* row = s.urow(d);
        for (size_t i = 0; i < n; ++i) {
          row[i] = std::clamp(rqmc_point(scramble, j0 + i, d), 0x1.0p-54, 1.0 - 0x1.0p-53);
        }
      }
      return false;
    }
    std::array<double*, 1024> rows{};
    for (uint32_t d = 0; d < U; ++d) rows[d] = s.urow(d);
    if (interlacing_ > 1) {
      // A higher-order net: the same affine scramble of interlacing x U dimensions,
      // interlaced (qmc.hpp), likewise built once per randomization and thread.
      thread_local std::optional<InterlacedSobolSet> hi;
      thread_local uint64_t hi_seed = 0;
      if (!hi || hi_seed != scramble || hi->dimensions() != U || hi->interlacing() != interlacing_) {
        hi.emplace(scramble, U, interlacing_);
        hi_seed = scramble;
      }
      hi->fill(static_cast<uint32_t>(j0), n, rows.data());
      return false;
    }
    // One scrambled point set per randomization (= sample), built once per thread and
    // reused for the batches of that set.
    thread_local std::optional<ScrambledSobolSet> set;
    thread_local uint64_t set_seed = 0;
    if (!set || set_seed != scramble || set->dimensions() != U) {
      set.emplace(scramble, U);
      set_seed = scramble;
    }
    set->fill(static_cast<uint32_t>(j0), n, rows.data());
    return false;
  }

 private:
  bool owen_;
  uint32_t interlacing_;  // 1: the Sobol' net itself; 2 or 3: interlaced (higher order)
};

// A randomly shifted rank-1 lattice: point k of shift `sample` is
// frac(k z / n + Delta), Delta uniform in [0,1)^s from the sample's own counter-based
// stream (so shifts are independent and a resumed job draws the same ones), then
// periodized per coordinate. One sample is the mean over the n points of one shift.
class LatticeKernel final : public SweepKernelBase {
 public:
  LatticeKernel(IntegrationProblem p, LatticeRule rule, Periodization per)
      : SweepKernelBase(std::move(p), rule.n), rule_(std::move(rule)), per_(per) {}

 protected:
  bool sweep_uniforms(Scratch& s, uint64_t sample, uint64_t j0, size_t n) const override {
    const uint32_t U = p_.domain->uniforms();
    const SampleRng shift(key_, sample);
    const uint64_t N = rule_.n;
    const double inv_n = 1.0 / static_cast<double>(N);
    if (per_ == Periodization::cubic) std::fill(s.pdf.begin(), s.pdf.begin() + static_cast<std::ptrdiff_t>(n), 1.0);
    for (uint32_t d = 0; d < U; ++d) {
      double* row = s.urow(d);
      const double delta = shift.uniform(d);
      const uint64_t z = rule_.z[d];
      for (size_t i = 0; i < n; ++i) {
        const uint64_t m = (j0 + i) * z % N;  // exact: j0 + i < n < 2^32, z < n
        double u = static_cast<double>(m) * inv_n + delta;
        u -= u >= 1.0 ? 1.0 : 0.0;
        u = periodized(u, per_, &s.pdf[i]);
        // Inside the open cube, as every other estimator's points (1/x, log x stay finite).
        row[i] = std::clamp(u, 0x1.0p-54, 1.0 - 0x1.0p-53);
      }
    }
    return per_ == Periodization::cubic;
  }

 private:
  LatticeRule rule_;
  Periodization per_;
};

class RejectionKernel final : public IntegrationKernelBase {
 public:
  RejectionKernel(IntegrationProblem p, uint32_t max_attempts)
      : IntegrationKernelBase(std::move(p)), max_attempts_(max_attempts) {}

 protected:
  size_t fill(uint64_t first, uint64_t count, double* values, BlockResult& out) const override {
    Scratch& s = scratch();
    const Domain& D = *p_.domain;
    const size_t d = D.dimensions();
    s.ensure(0, d);
    const double measure = D.measure();
    std::vector<double> pt(d);
    size_t written = 0;
    uint64_t next = 0;
    while (next < count) {
      // Gather up to one batch of accepted points.
      size_t n = 0;
      uint64_t first_in_batch = first + next;
      while (n < kB && next < count) {
        const SampleRng rng(key_, first + next);
        ++next;
        bool accepted = false;
        for (uint32_t a = 0; a < max_attempts_; ++a) {
          out.counters.add(IntegrationCounter::rejection_attempts);
          for (size_t k = 0; k < d; ++k) {
            const double u = rng.open_uniform(a * static_cast<uint32_t>(d) + static_cast<uint32_t>(k));
            pt[k] = D.lower()[k] + u * (D.upper()[k] - D.lower()[k]);
          }
          if (D.contains(pt.data())) {
            accepted = true;
            break;
          }
        }
        if (!accepted) {
          out.counters.add(IntegrationCounter::rejection_failures);
          continue;
        }
        out.counters.add(IntegrationCounter::rejection_accepts);
        for (size_t k = 0; k < d; ++k) s.x_ptr[k][n] = pt[k];
        ++n;
      }
      double* v = values + written;
      p_.integrand->evaluate_batch(s.x_cptr.data(), n, v);
      for (size_t i = 0; i < n; ++i) v[i] *= measure;
      out.counters.add(IntegrationCounter::evaluations, n);
      const size_t ok = check(v, n, first_in_batch, s, out);
      written += ok;
      if (ok < n) return written;
    }
    return written;
  }

 private:
  uint32_t max_attempts_;
};

// The rule's grid is cut into chunks of at most kChunk points, one partition each
// (fine grid first, then the coarse one), so no block runs for long: cancel and
// shutdown act between blocks, and chunks run in parallel. Channel p holds chunk p's
// partial sum; T(n) and T(m) are the partial sums added in chunk order. A grid of
// one chunk per rule has exactly the old layout (channel 0 = T(n), channel 1 = T(m)).
class TrapezoidKernel final : public Kernel {
 public:
  static constexpr uint64_t kChunk = uint64_t{1} << 17;

  TrapezoidKernel(IntegrationProblem p, uint32_t n) : p_(std::move(p)), n_(n), m_((n + 1) / 2) {
    fine_points_ = grid_points(n_);
    fine_chunks_ = chunks(fine_points_);
    coarse_chunks_ = chunks(grid_points(m_));
  }
  size_t channel_count() const override { return fine_chunks_ + coarse_chunks_; }
  uint32_t partition_count() const override { return static_cast<uint32_t>(fine_chunks_ + coarse_chunks_); }
  PassSchedule schedule() const override { return {1, 1, 1}; }
  std::span<const std::string_view> counter_names() const override { return integration_counter_names(); }
  std::vector<std::string> warnings(const JobState& st) const override { return integration_counter_warnings(st); }

  void run_block(const Block& b, BlockResult& out) const override {
    out.first_channel = b.partition;
    out.tallies.assign(1, Tally{});
    if (b.first_sample > 0) {
      // The rule is deterministic: further samples would repeat the same value.
      return;
    }
    const bool fine = b.partition < fine_chunks_;
    const uint32_t n = fine ? n_ : m_;
    const uint64_t chunk = fine ? b.partition : b.partition - fine_chunks_;
    const uint64_t total = grid_points(n);
    const uint64_t begin = chunk * kChunk;
    double sum = 0.0;
    if (!rule(n, begin, std::min(total, begin + kChunk), sum, out)) return;
    out.tallies[0].add(sum);
  }

  // T(n), T(m) as the sums of their chunks (nullopt until every chunk is in).
  std::optional<std::pair<double, double>> totals(const JobState& st) const {
    if (st.channels.size() != channel_count()) return std::nullopt;
    double fine = 0.0, coarse = 0.0;
    for (size_t c = 0; c < st.channels.size(); ++c) {
      if (st.channels[c].n == 0) return std::nullopt;
      (c < fine_chunks_ ? fine : coarse) += st.channels[c].mean;
    }
    return std::make_pair(fine, coarse);
  }

  std::optional<Headline> headline(const JobState& st) const override {
    if (channel_count() == 2) return std::nullopt;  // channel 0 is T(n)
    Headline h;
    const auto t = totals(st);
    h.mean = t ? t->first : std::numeric_limits<double>::quiet_NaN();
    h.std_error = std::numeric_limits<double>::quiet_NaN();
    return h;
  }

  // Error: |T(n) - T(m)| / 3, Richardson's estimate for an O(h^2) rule when m ~ n/2.
  ErrorSummary error_summary(const JobState& st, double) const override {
    ErrorSummary e;
    const auto t = totals(st);
    if (!t) {
      e.abs_error = e.rel_error = std::numeric_limits<double>::infinity();
      return e;
    }
    e.mean = t->first;
    e.abs_error = std::fabs(t->first - t->second) / 3.0;
    e.rel_error = e.mean != 0.0 ? e.abs_error / std::fabs(e.mean) : std::numeric_limits<double>::infinity();
    e.sigma = std::numeric_limits<double>::quiet_NaN();
    return e;
  }

 private:
  uint64_t grid_points(uint32_t n) const {
    uint64_t total = 1;
    for (size_t k = 0; k < p_.domain->dimensions(); ++k) total *= n;
    return total;
  }
  static size_t chunks(uint64_t points) { return static_cast<size_t>((points + kChunk - 1) / kChunk); }

  // Adds the weighted values of grid points [begin, end) of the n-point rule.
  bool rule(uint32_t n, uint64_t begin, uint64_t end, double& result, BlockResult& out) const {
    const Domain& D = *p_.domain;
    const size_t d = D.dimensions();
    Scratch& s = scratch();
    s.ensure(0, d);
    std::vector<double> h(d);
    for (size_t k = 0; k < d; ++k) h[k] = (D.upper()[k] - D.lower()[k]) / (n - 1);
    double sum = 0.0;
    std::vector<double> w(kB);
    for (uint64_t j0 = begin; j0 < end; j0 += kB) {
      if (block_abandoned()) return false;  // its result is dropped (block_abandon.hpp)
      const size_t cnt = static_cast<size_t>(std::min<uint64_t>(kB, end - j0));
      for (size_t i = 0; i < cnt; ++i) {
        uint64_t idx = j0 + i;
        double weight = 1.0;
        for (size_t k = 0; k < d; ++k) {
          const uint64_t c = idx % n;
          idx /= n;
          s.x_ptr[k][i] = c + 1 == n ? D.upper()[k] : D.lower()[k] + static_cast<double>(c) * h[k];
          weight *= (c == 0 || c + 1 == n) ? 0.5 * h[k] : h[k];
        }
        w[i] = weight;
      }
      p_.integrand->evaluate_batch(s.x_cptr.data(), cnt, s.f.data());
      out.counters.add(IntegrationCounter::evaluations, cnt);
      for (size_t i = 0; i < cnt; ++i) {
        if (!std::isfinite(s.f[i])) {
          out.counters.add(IntegrationCounter::nonfinite);
          record_fault(out, j0 + i, s.f[i], s, i, d);
          return false;
        }
        sum += w[i] * s.f[i];
      }
    }
    result = sum;
    return true;
  }

  IntegrationProblem p_;
  uint32_t n_, m_;
  uint64_t fine_points_ = 0;
  size_t fine_chunks_ = 0, coarse_chunks_ = 0;
};

}  // namespace

std::shared_ptr<const Kernel> make_uniform_kernel(IntegrationProblem p) {
  return std::make_shared<UniformKernel>(std::move(p));
}
std::shared_ptr<const Kernel> make_power_importance_kernel(IntegrationProblem p, PowerDensity d) {
  return std::make_shared<PowerImportanceKernel>(std::move(p), std::move(d));
}
std::shared_ptr<const Kernel> make_tabulated_importance_kernel(IntegrationProblem p,
                                                               TabulatedDensity d) {
  return std::make_shared<TabulatedImportanceKernel>(std::move(p), std::move(d));
}
std::shared_ptr<const Kernel> make_cosine_importance_kernel(IntegrationProblem p) {
  return std::make_shared<CosineImportanceKernel>(std::move(p));
}
std::shared_ptr<const Kernel> make_stratified_kernel(IntegrationProblem p, uint32_t k, uint32_t s) {
  return std::make_shared<StratifiedKernel>(std::move(p), k, s);
}
std::shared_ptr<const Kernel> make_qmc_kernel(IntegrationProblem p, uint32_t points, bool owen, uint32_t interlacing) {
  return std::make_shared<QmcKernel>(std::move(p), points, owen, interlacing);
}
std::shared_ptr<const Kernel> make_lattice_kernel(IntegrationProblem p, LatticeRule rule, Periodization per) {
  return std::make_shared<LatticeKernel>(std::move(p), std::move(rule), per);
}
std::shared_ptr<const Kernel> make_rejection_kernel(IntegrationProblem p, uint32_t max_attempts) {
  return std::make_shared<RejectionKernel>(std::move(p), max_attempts);
}
std::shared_ptr<const Kernel> make_trapezoid_kernel(IntegrationProblem p, uint32_t n) {
  return std::make_shared<TrapezoidKernel>(std::move(p), n);
}

}  // namespace tally
