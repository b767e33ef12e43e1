#include "common/integrate/vegas.hpp"

#include <algorithm>
#include <boost/math/distributions/chi_squared.hpp>
#include <cmath>
#include <fmt/format.h>
#include <limits>
#include <stdexcept>

#include "common/engine/byte_codec.hpp"
#include "common/integrate/integration_counters.hpp"
#include "common/rng/counter_rng.hpp"
#include "common/stats/confidence.hpp"

namespace tally {

namespace {

constexpr size_t kB = kIntegrandBatch;
constexpr uint64_t kStateMagic = 0x3153414745565441ULL;   // "ATVEGAS1"
constexpr uint64_t kStateMagic2 = 0x3253414745565441ULL;  // "ATVEGAS2": + VEGAS+ hypercube weights

// kernel_state and pass_input are written with the engine's codec (byte_codec.hpp:
// little-endian u64, doubles as their bits). States written before by a little-endian
// host's byte order are the same bytes (tests/integrate/data/vegas_state_v*.bin).
using StateReader = ByteReader<std::runtime_error>;

struct Grid {
  uint32_t d = 0, nb = 0;
  std::vector<double> edges;  // d * (nb + 1)
  const double* axis(size_t k) const { return edges.data() + k * (nb + 1); }
  double* axis(size_t k) { return edges.data() + k * (nb + 1); }
  static Grid uniform(uint32_t d, uint32_t nb) {
    Grid g{d, nb, std::vector<double>(static_cast<size_t>(d) * (nb + 1))};
    for (size_t k = 0; k < d; ++k) {
      for (uint32_t j = 0; j <= nb; ++j) g.axis(k)[j] = static_cast<double>(j) / nb;
    }
    return g;
  }
};

struct State {
  Grid grid;
  uint32_t m = 1;
  // VEGAS+: per hypercube, sigma_h^beta from the last pass (the next pass's allocation
  // weights); empty without stratification or before the first pass.
  std::vector<double> hweights;
  std::vector<VegasIteration> iterations;        // component 0 (report)
  std::vector<std::vector<Tally>> components;    // per iteration, all m components
};

std::string encode_state(const State& s) {
  ByteWriter o;
  o.u64(s.hweights.empty() ? kStateMagic : kStateMagic2);
  o.u64(s.grid.d);
  o.u64(s.grid.nb);
  o.u64(s.m);
  for (double e : s.grid.edges) o.f64(e);
  if (!s.hweights.empty()) {
    o.u64(s.hweights.size());
    for (double w : s.hweights) o.f64(w);
  }
  o.u64(s.iterations.size());
  for (size_t k = 0; k < s.iterations.size(); ++k) {
    o.u64(s.iterations[k].warmup ? 1 : 0);
    for (const Tally& t : s.components[k]) o.tally(t);
  }
  return o.take();
}

std::optional<State> decode_state(std::string_view bytes) {
  if (bytes.empty()) return std::nullopt;
  StateReader in(bytes, "VEGAS state");
  const uint64_t magic = in.u64();
  if (magic != kStateMagic && magic != kStateMagic2) return std::nullopt;
  State s;
  s.grid.d = static_cast<uint32_t>(in.u64());
  s.grid.nb = static_cast<uint32_t>(in.u64());
  s.m = static_cast<uint32_t>(in.u64());
  if (s.grid.d == 0 || s.grid.d > 4096 || s.grid.nb == 0 || s.grid.nb > (1u << 20) || s.m == 0 || s.m > 4096) {
    throw std::runtime_error("VEGAS state is corrupt");
  }
  s.grid.edges.resize(static_cast<size_t>(s.grid.d) * (s.grid.nb + 1));
  for (double& e : s.grid.edges) e = in.f64();
  if (magic == kStateMagic2) {
    const uint64_t h = in.u64();
    if (h == 0 || h > kVegasRound) throw std::runtime_error("VEGAS state is corrupt");
    s.hweights.resize(h);
    for (double& w : s.hweights) w = in.f64();
  }
  const uint64_t k = in.u64();
  if (k > (uint64_t{1} << 32)) throw std::runtime_error("VEGAS state is corrupt");
  for (uint64_t i = 0; i < k; ++i) {
    VegasIteration it;
    it.warmup = in.u64() != 0;
    std::vector<Tally> comps(s.m);
    for (Tally& t : comps) t = in.tally();
    it.tally = comps[0];
    s.iterations.push_back(it);
    s.components.push_back(std::move(comps));
  }
  return s;
}

// Lepage's refinement of one axis from its per-bin sums of (f/p)^2: smooth over
// neighbours, compress with ((r - 1) / ln r)^alpha (r = the bin's share), then move
// the edges so that every new bin holds an equal share of the weight.
void refine_axis(double* edges, uint32_t nb, std::vector<double> d, double alpha) {
  if (nb < 2 || alpha <= 0.0) return;
  {
    std::vector<double> s(nb);
    s[0] = 0.5 * (d[0] + d[1]);
    s[nb - 1] = 0.5 * (d[nb - 2] + d[nb - 1]);
    for (uint32_t j = 1; j + 1 < nb; ++j) s[j] = (d[j - 1] + d[j] + d[j + 1]) / 3.0;
    d = std::move(s);
  }
  double total = 0.0;
  for (double v : d) total += v;
  if (!(total > 0.0) || !std::isfinite(total)) return;
  std::vector<double> w(nb, 0.0);
  double wsum = 0.0;
  for (uint32_t j = 0; j < nb; ++j) {
    const double r = d[j] / total;
    if (r > 0.0) {
      // (r - 1) / ln r -> 1 as r -> 1; r < 1 here unless one bin holds everything.
      w[j] = r < 1.0 ? std::pow((r - 1.0) / std::log(r), alpha) : 1.0;
    }
    wsum += w[j];
  }
  if (!(wsum > 0.0)) return;
  // Defensive floor: no bin's weight below kFloor of the mean, so no bin grows past
  // ~1/kFloor times the mean width. Without it a bin holding a jump (half of its
  // samples 0, the other half near the integrand's largest values) keeps widening,
  // its density falls where f is largest, and rare huge f/p spikes follow.
  constexpr double kFloor = 0.2;
  const double floor = kFloor * wsum / nb;
  wsum = 0.0;
  for (double& v : w) {
    v = std::max(v, floor);
    wsum += v;
  }
  const double per = wsum / nb;
  std::vector<double> out(nb + 1);
  out[0] = 0.0;
  out[nb] = 1.0;
  uint32_t i = 1;
  double acc = 0.0;
  double xnew = edges[0];
  for (uint32_t j = 0; j < nb && i < nb; ++j) {
    acc += w[j];
    const double xold = xnew;
    xnew = edges[j + 1];
    while (acc > per && i < nb) {
      acc -= per;
      out[i++] = xnew - (xnew - xold) * acc / w[j];
    }
  }
  for (; i < nb; ++i) out[i] = 1.0;  // rounding left the last edges unplaced
  for (uint32_t j = 1; j <= nb; ++j) out[j] = std::max(out[j], out[j - 1]);  // monotone
  std::copy(out.begin(), out.end(), edges);
}

// Uniform number k of sample `index` of the stream `key`, in (0, 1).
inline double axis_uniform(uint64_t key, uint64_t index, uint32_t k) {
  const uint64_t base = SampleRng::sample_base(key, index);
  const auto bits = static_cast<int64_t>(SampleRng::bits_at(base, k) >> 11);
  return (static_cast<double>(bits) + 0.5) * 0x1.0p-53;
}

// The grid map of one sample at t = y nb (y in [0, 1)): bin j = floor(t) and the offset
// t - j inside it; x = lo + w * (edge_j + offset * width_j); the density factor
// 1 / (nb * width_j) goes into the Jacobian as nb * width_j.
inline void grid_map(const double* e, const double* wd, uint32_t nb, double fnb, double t, double lo, double w,
                     double& x, double& jac, uint32_t& bk) {
  uint32_t j = static_cast<uint32_t>(t);
  if (j >= nb) j = nb - 1;
  const double frac = t - static_cast<double>(j);
  x = lo + w * (e[j] + frac * wd[j]);
  jac *= fnb * wd[j];
  bk = j;
}

// Axis k of samples [first, first + n): a uniform u is mapped through the grid at u nb.
void map_axis(const double* e, const double* wd, uint32_t nb, uint64_t key, uint64_t first, size_t n, uint32_t k,
              double lo, double w, double* x, double* jac, uint32_t* bk) {
  const double fnb = static_cast<double>(nb);
  for (size_t i = 0; i < n; ++i) {
    grid_map(e, wd, nb, fnb, axis_uniform(key, first + i, k) * fnb, lo, w, x[i], jac[i], bk[i]);
  }
}

// VEGAS+: axis k of samples whose hypercube is hc[i] (digit k of hc in base ns is the
// stratum along the axis): y = (stratum + u) / ns, then the grid map as above.
void map_axis_strat(const double* e, const double* wd, uint32_t nb, uint64_t key, uint64_t first, size_t n,
                    uint32_t k, uint32_t ns, uint64_t stride, const uint32_t* hc, double lo, double w, double* x,
                    double* jac, uint32_t* bk) {
  const double fnb = static_cast<double>(nb);
  const double fns = static_cast<double>(ns);
  for (size_t i = 0; i < n; ++i) {
    const double stratum = static_cast<double>((hc[i] / stride) % ns);
    const double t = (stratum + axis_uniform(key, first + i, k)) / fns * fnb;
    grid_map(e, wd, nb, fnb, t, lo, w, x[i], jac[i], bk[i]);
  }
}

// Samples per hypercube in one round of R: 2 each, the rest in proportion to the
// weights, cumulated so that the counts add up to R exactly. Equal weights when they
// carry no information (first pass, all zero).
std::vector<uint64_t> allocation_bounds(std::vector<double> w, uint64_t H, uint64_t R) {
  double total = 0.0;
  for (double v : w) total += v;
  if (w.size() != H || !(total > 0.0) || !std::isfinite(total)) {
    w.assign(H, 1.0);
    total = static_cast<double>(H);
  }
  const uint64_t extra = R - 2 * H;
  std::vector<uint64_t> c(H + 1, 0);
  double acc = 0.0;
  for (uint64_t h = 0; h < H; ++h) {
    acc += w[h];
    const double share = std::min(1.0, acc / total);
    c[h + 1] = 2 * (h + 1) + static_cast<uint64_t>(std::floor(static_cast<double>(extra) * share));
    c[h + 1] = std::max(c[h + 1], c[h] + 2);
  }
  c[H] = R;
  return c;
}

uint64_t ipow(uint64_t b, size_t e) {
  uint64_t r = 1;
  for (size_t i = 0; i < e; ++i) r *= b;
  return r;
}

class VegasKernel final : public Kernel {
 public:
  VegasKernel(IntegrationProblem p, VegasOptions o)
      : p_(std::move(p)),
        o_(o),
        key_(stream_key(p_.seed, 0)),
        d_(static_cast<uint32_t>(p_.domain->dimensions())),
        m_(static_cast<uint32_t>(p_.integrand->components())) {
    if (!p_.domain->is_box()) throw std::invalid_argument("VEGAS needs a box domain");
    if (o_.bins < 2) throw std::invalid_argument("VEGAS needs at least 2 bins");
    measure_ = p_.domain->measure();
    if (o_.stratify) {
      ns_ = vegas_strata_per_axis(d_);
      H_ = ipow(ns_, d_);
    }
  }

  // Components, then (with covariance) one channel per pair (c < c') holding f_c + f_c'.
  size_t channel_count() const override {
    return m_ + (p_.covariance ? static_cast<size_t>(m_) * (m_ - 1) / 2 : 0);
  }

  PassSchedule schedule() const override {
    PassSchedule s;
    // The grid adapts once per pass, so passes stay short (at most 2^17 samples,
    // ~10 ms for a cheap integrand): a long run keeps refining its grid.
    // A block holds its values per component (m x block_samples doubles): many components
    // get shorter blocks, so a thread's buffer stays near 1 MB per 64 components.
    s.block_samples = m_ <= 64 ? 2048 : std::max<uint64_t>(256, (2048 * 64 / m_) / 256 * 256);
    s.first_pass_samples = 4096;
    s.max_pass_samples = o_.max_pass_samples;
    if (o_.stratify) s.sample_quantum = kVegasRound;  // passes of whole rounds
    return s;
  }

  std::string pass_input(const JobState& st) const override {
    const std::optional<State> s = decode_state(st.kernel_state);
    const Grid g = s ? s->grid : Grid::uniform(d_, o_.bins);
    if (g.d != d_ || g.nb != o_.bins) throw std::runtime_error("VEGAS state does not match the job");
    ByteWriter o;
    o.u64(st.passes < o_.warmup_passes ? 1 : 0);
    for (double e : g.edges) o.f64(e);
    if (o_.stratify) {
      // Where the pass starts (rounds count from there) and its allocation bounds.
      o.u64(st.partition_samples.empty() ? st.samples : st.partition_samples[0]);
      const std::vector<uint64_t> c =
          allocation_bounds(s ? s->hweights : std::vector<double>{}, H_, kVegasRound);
      for (uint64_t v : c) o.u64(v);
    }
    return o.take();
  }

  void run_block(const Block& b, BlockResult& out) const override {
    JobState empty;
    run_block_with(b, pass_input(empty), out);
  }

  void run_block_with(const Block& b, std::string_view input, BlockResult& out) const override {
    const size_t grid_values = static_cast<size_t>(d_) * (o_.bins + 1);
    const size_t strat_values = o_.stratify ? 1 + H_ + 1 : 0;
    if (input.size() != 8 * (1 + grid_values + strat_values)) {
      throw std::runtime_error("VEGAS pass input has the wrong size");
    }
    StateReader in(input, "VEGAS pass input");
    const uint64_t warm_flag = in.u64();
    thread_local std::vector<double> edges;
    edges.resize(grid_values);
    for (double& e : edges) e = in.f64();
    uint64_t pass_start = 0;
    thread_local std::vector<uint64_t> bounds;
    thread_local std::vector<uint32_t> hcube;
    thread_local std::vector<double> hwt;
    if (o_.stratify) {
      pass_start = in.u64();
      bounds.resize(H_ + 1);
      for (uint64_t& v : bounds) v = in.u64();
      if (b.first_sample < pass_start || bounds[H_] != kVegasRound) {
        throw std::runtime_error("VEGAS+ pass input does not match the block");
      }
      hcube.resize(kB);
      hwt.resize(kB);
    }
    const bool warmup = warm_flag != 0;
    const uint32_t nb = o_.bins;
    thread_local std::vector<double> widths, jac, xs, vals;
    thread_local std::vector<uint32_t> bins;
    thread_local std::vector<const double*> xptr;
    thread_local std::vector<double*> vptr;
    widths.resize(static_cast<size_t>(d_) * nb);
    for (size_t k = 0; k < d_; ++k) {
      for (uint32_t j = 0; j < nb; ++j) {
        widths[k * nb + j] = edges[k * (nb + 1) + j + 1] - edges[k * (nb + 1) + j];
      }
    }
    const size_t count = static_cast<size_t>(b.sample_count);
    jac.resize(kB);
    xs.resize(static_cast<size_t>(d_) * kB);
    bins.resize(static_cast<size_t>(d_) * kB);
    vals.resize(static_cast<size_t>(m_) * count);
    xptr.resize(d_);
    vptr.resize(m_);
    for (size_t k = 0; k < d_; ++k) xptr[k] = xs.data() + k * kB;
    const size_t nsums = static_cast<size_t>(m_) * d_ * nb;
    out.aux.assign(nsums + 3 * static_cast<size_t>(m_), 0.0);
    double* sums = out.aux.data();
    const Domain& D = *p_.domain;
    size_t ok_total = count;
    // VEGAS+: per hypercube and component, the tally of f/p (unweighted) over this
    // block's samples; the hypercube of position r in a round is the h with
    // bounds[h] <= r < bounds[h + 1], walked along as r advances.
    thread_local std::vector<Tally> htally;
    if (o_.stratify) htally.assign(H_ * m_, Tally{});
    uint64_t h_cur = 0;
    uint64_t h_lo = H_, h_hi = 0;
    if (o_.stratify) {
      const uint64_t r0 = (b.first_sample - pass_start) % kVegasRound;
      h_cur = static_cast<uint64_t>(std::upper_bound(bounds.begin(), bounds.end(), r0) - bounds.begin()) - 1;
    }
    for (size_t off = 0; off < count; off += kB) {
      const size_t n = std::min(kB, count - off);
      std::fill(jac.begin(), jac.begin() + static_cast<std::ptrdiff_t>(n), measure_);
      if (o_.stratify) {
        for (size_t i = 0; i < n; ++i) {
          const uint64_t r = (b.first_sample + off + i - pass_start) % kVegasRound;
          if (r == 0) h_cur = 0;
          while (r >= bounds[h_cur + 1]) ++h_cur;
          hcube[i] = static_cast<uint32_t>(h_cur);
          // 1 / (sample density in y relative to uniform) = R / (H n_h)
          hwt[i] = static_cast<double>(kVegasRound) /
                   (static_cast<double>(H_) * static_cast<double>(bounds[h_cur + 1] - bounds[h_cur]));
        }
        uint64_t stride = 1;
        for (size_t k = 0; k < d_; ++k) {
          map_axis_strat(edges.data() + k * (nb + 1), widths.data() + k * nb, nb, key_, b.first_sample + off, n,
                         static_cast<uint32_t>(k), ns_, stride, hcube.data(), D.lower()[k],
                         D.upper()[k] - D.lower()[k], xs.data() + k * kB, jac.data(), bins.data() + k * kB);
          stride *= ns_;
        }
      } else {
        for (size_t k = 0; k < d_; ++k) {
          map_axis(edges.data() + k * (nb + 1), widths.data() + k * nb, nb, key_, b.first_sample + off, n,
                   static_cast<uint32_t>(k), D.lower()[k], D.upper()[k] - D.lower()[k], xs.data() + k * kB,
                   jac.data(), bins.data() + k * kB);
        }
      }
      for (size_t c = 0; c < m_; ++c) vptr[c] = vals.data() + c * count + off;
      p_.integrand->evaluate_components(xptr.data(), n, vptr.data());
      out.counters.add(IntegrationCounter::evaluations, n);
      size_t ok = n;
      for (size_t c = 0; c < m_; ++c) {
        double* v = vptr[c];
        for (size_t i = 0; i < n; ++i) v[i] *= jac[i];
        for (size_t i = 0; i < ok; ++i) {
          if (!std::isfinite(v[i])) {
            record_fault(out, b.first_sample + off + i, v[i], static_cast<uint32_t>(c), xs.data(), i);
            ok = i;
            break;
          }
        }
      }
      if (o_.stratify) {
        // Per-hypercube tallies of f/p, then f/p weighted by R / (H n_h): the grid's
        // training sums and the channels see samples as if drawn uniformly in y.
        for (size_t c = 0; c < m_; ++c) {
          double* v = vptr[c];
          for (size_t i = 0; i < ok; ++i) htally[hcube[i] * m_ + c].add(v[i]);
          for (size_t k = 0; k < d_; ++k) {
            double* s = sums + (c * d_ + k) * nb;
            const uint32_t* bk = bins.data() + k * kB;
            for (size_t i = 0; i < ok; ++i) s[bk[i]] += v[i] * v[i] * hwt[i];
          }
          for (size_t i = 0; i < ok; ++i) v[i] *= hwt[i];
        }
        for (size_t i = 0; i < ok; ++i) {
          h_lo = std::min<uint64_t>(h_lo, hcube[i]);
          h_hi = std::max<uint64_t>(h_hi, hcube[i]);
        }
      } else {
        for (size_t c = 0; c < m_; ++c) {
          const double* v = vptr[c];
          for (size_t k = 0; k < d_; ++k) {
            double* s = sums + (c * d_ + k) * nb;
            const uint32_t* bk = bins.data() + k * kB;
            for (size_t i = 0; i < ok; ++i) s[bk[i]] += v[i] * v[i];
          }
        }
      }
      if (ok < n) {
        ok_total = off + ok;
        break;
      }
    }
    // The block's tally per component (aux tail) for the pass's own record.
    std::vector<Tally> comp(m_);
    for (size_t c = 0; c < m_; ++c) {
      comp[c] = Tally::from_batch(vals.data() + c * count, ok_total);
      out.aux[nsums + 3 * c] = static_cast<double>(comp[c].n);
      out.aux[nsums + 3 * c + 1] = comp[c].mean;
      out.aux[nsums + 3 * c + 2] = comp[c].m2;
    }
    if (o_.stratify) {
      // aux tail: h_lo, count, then per hypercube in [h_lo, h_lo + count) and component
      // its tally (n, mean, m2).
      const uint64_t cnt = h_lo <= h_hi ? h_hi - h_lo + 1 : 0;
      out.aux.push_back(static_cast<double>(h_lo <= h_hi ? h_lo : 0));
      out.aux.push_back(static_cast<double>(cnt));
      for (uint64_t h = h_lo; h < h_lo + cnt; ++h) {
        for (size_t c = 0; c < m_; ++c) {
          const Tally& t = htally[h * m_ + c];
          out.aux.push_back(static_cast<double>(t.n));
          out.aux.push_back(t.mean);
          out.aux.push_back(t.m2);
        }
      }
    }
    out.first_channel = 0;
    out.tallies.assign(channel_count(), Tally{});
    if (warmup) return;
    for (size_t c = 0; c < m_; ++c) out.tallies[c] = comp[c];
    size_t ch = m_;
    thread_local std::vector<double> pair;
    pair.resize(ok_total);
    for (size_t a = 0; a < m_ && p_.covariance; ++a) {
      for (size_t c = a + 1; c < m_; ++c) {
        const double* va = vals.data() + a * count;
        const double* vc = vals.data() + c * count;
        for (size_t i = 0; i < ok_total; ++i) pair[i] = va[i] + vc[i];
        out.tallies[ch++] = Tally::from_batch(pair.data(), ok_total);
      }
    }
    const double* v0 = vals.data();
    double threshold = out.tail.threshold();
    for (size_t i = 0; i < ok_total; ++i) {
      const double a = std::fabs(v0[i]);
      if (a > threshold) {
        out.tail.offer(a);
        threshold = out.tail.threshold();
      }
    }
  }

  bool folds_passes() const override { return true; }
  void fold_pass(std::string_view input, const std::vector<BlockResult>& results, JobState& st) const override {
    State s;
    if (auto old = decode_state(st.kernel_state)) {
      s = std::move(*old);
    } else {
      s.grid = Grid::uniform(d_, o_.bins);
      s.m = m_;
    }
    const uint64_t warm_flag = input.size() >= 8 ? StateReader(input, "VEGAS pass input").u64() : 0;
    const uint32_t nb = o_.bins;
    const size_t nsums = static_cast<size_t>(m_) * d_ * nb;
    std::vector<double> sums(nsums, 0.0);
    std::vector<Tally> comps(m_);
    std::vector<Tally> hsum(o_.stratify ? H_ * m_ : 0);
    const size_t head = nsums + 3 * static_cast<size_t>(m_);
    for (const BlockResult& r : results) {  // block order
      if (o_.stratify) {
        if (r.aux.size() < head + 2) continue;  // cancelled or faulted block
        const auto h_lo = static_cast<uint64_t>(r.aux[head]);
        const auto cnt = static_cast<uint64_t>(r.aux[head + 1]);
        if (h_lo + cnt > H_ || r.aux.size() != head + 2 + 3 * cnt * m_) continue;
        const double* a = r.aux.data() + head + 2;
        for (uint64_t h = h_lo; h < h_lo + cnt; ++h) {
          for (size_t c = 0; c < m_; ++c, a += 3) {
            Tally t;
            t.n = static_cast<uint64_t>(a[0]);
            t.mean = a[1];
            t.m2 = a[2];
            hsum[h * m_ + c].merge(t);
          }
        }
      } else if (r.aux.size() != head) {
        continue;  // cancelled or faulted block
      }
      for (size_t i = 0; i < nsums; ++i) sums[i] += r.aux[i];
      for (size_t c = 0; c < m_; ++c) {
        Tally t;
        t.n = static_cast<uint64_t>(r.aux[nsums + 3 * c]);
        t.mean = r.aux[nsums + 3 * c + 1];
        t.m2 = r.aux[nsums + 3 * c + 2];
        comps[c].merge(t);
      }
    }
    // Steering (vector integrands): every component's per-axis bin sums normalized to
    // a total of 1 and added, so each component pulls the grid equally whatever its
    // scale; with one component this is Lepage's rule unchanged.
    for (size_t k = 0; k < d_; ++k) {
      std::vector<double> dk(nb, 0.0);
      for (size_t c = 0; c < m_; ++c) {
        const double* sc = sums.data() + (c * d_ + k) * nb;
        double tot = 0.0;
        for (uint32_t j = 0; j < nb; ++j) tot += sc[j];
        if (!(tot > 0.0) || !std::isfinite(tot)) continue;
        const double inv = 1.0 / tot;
        for (uint32_t j = 0; j < nb; ++j) dk[j] += sc[j] * inv;
      }
      refine_axis(s.grid.axis(k), nb, std::move(dk), o_.alpha);
    }
    bool usable = true;
    if (o_.stratify) {
      // The pass estimate per component: sum_h mean_h / H, its variance
      // sum_h s_h^2 / n_h / H^2, as a tally of the pass's n samples with that mean and
      // variance per sample n * var (what the combination rule reads). A pass cut short
      // (fewer than 2 samples in some hypercube: a sample limit below one round) is
      // not used in the estimate. The next allocation: sigma_h^beta, summed over
      // components after normalising each to total 1.
      std::vector<double> w(H_, 0.0);
      const double fH = static_cast<double>(H_);
      for (size_t c = 0; c < m_; ++c) {
        double mean = 0.0, var = 0.0, vtot = 0.0;
        uint64_t n = 0;
        for (uint64_t h = 0; h < H_; ++h) {
          const Tally& t = hsum[h * m_ + c];
          n += t.n;
          if (t.n < 2) {
            usable = false;
            continue;
          }
          mean += t.mean;
          var += t.variance() / static_cast<double>(t.n);
          vtot += t.variance();
        }
        mean /= fH;
        var /= fH * fH;
        Tally pass;
        pass.n = n;
        pass.mean = mean;
        pass.m2 = var * static_cast<double>(n) * static_cast<double>(n > 0 ? n - 1 : 0);
        comps[c] = pass;
        if (vtot > 0.0 && std::isfinite(vtot)) {
          for (uint64_t h = 0; h < H_; ++h) {
            const Tally& t = hsum[h * m_ + c];
            if (t.n >= 2) w[h] += t.variance() / vtot;
          }
        }
      }
      for (double& v : w) v = std::pow(v, 0.5 * o_.beta);
      s.hweights = std::move(w);
    }
    VegasIteration it;
    it.tally = comps[0];
    it.warmup = warm_flag != 0 || !usable;
    s.iterations.push_back(it);
    s.components.push_back(std::move(comps));
    st.kernel_state = encode_state(s);
  }

  // Component c's mean and standard error as the stop rule reads them: the weighted
  // passes' (or the pooled samples'), scaled by the passes' disagreement; nullopt below
  // 2 samples or for a non-finite error.
  std::optional<std::pair<double, double>> component_mean_se(const JobState& st, const VegasReport& rep,
                                                             size_t c) const {
    const Tally& t = st.channels[c];  // the pooled post-warm-up samples
    if (t.n < 2) return std::nullopt;
    double mean = t.mean, se = t.std_error();
    if (o_.weighted) {
      mean = rep.combined_mean[c];
      se = rep.combined_std_error[c];
    }
    if (!std::isfinite(se)) return std::nullopt;
    return std::pair{mean, se * rep.error_scale};
  }

  ErrorSummary error_summary(const JobState& st, double confidence) const override {
    ErrorSummary worst;
    worst.abs_error = worst.rel_error = std::numeric_limits<double>::infinity();
    worst.sigma = std::numeric_limits<double>::quiet_NaN();
    if (st.channels.empty()) return worst;
    worst.mean = st.channels[0].mean;
    const std::optional<VegasReport> rep = vegas_report(st);
    if (!rep) return worst;
    bool any = false;
    for (size_t c = 0; c < m_ && c < st.channels.size(); ++c) {
      const Tally& t = st.channels[c];  // the pooled post-warm-up samples
      const auto ms = component_mean_se(st, *rep, c);
      if (!ms) return worst;
      const auto [mean, se] = *ms;
      const double z = critical_value(confidence, t.n);
      const double half = z * se;
      const double rel = mean != 0.0 ? half / std::fabs(mean)
                                     : (half == 0.0 ? 0.0 : std::numeric_limits<double>::infinity());
      if (!any || half > worst.abs_error) {
        worst.abs_error = half;
        // Per sample of the whole job (warm-up included): the runner predicts the
        // samples a target needs from sigma and JobState::samples, so this keeps
        // half = z * sigma / sqrt(samples) and the prediction counts the warm-up.
        worst.sigma = se * std::sqrt(static_cast<double>(std::max<uint64_t>(st.samples, t.n)));
        worst.mean = mean;
      }
      if (!any || rel > worst.rel_error) worst.rel_error = rel;
      any = true;
    }
    return worst;
  }

  std::vector<ComponentError> component_errors(const JobState& st, double confidence) const override {
    std::vector<ComponentError> out;
    const std::optional<VegasReport> rep = vegas_report(st);
    for (size_t c = 0; c < m_ && c < st.channels.size(); ++c) {
      const auto ms = rep ? component_mean_se(st, *rep, c) : std::nullopt;
      if (!ms) {
        out.push_back({std::numeric_limits<double>::infinity(), st.channels[c].mean});
        continue;
      }
      out.push_back({critical_value(confidence, st.channels[c].n) * ms->second, ms->first});
    }
    return out;
  }

  std::optional<Headline> headline(const JobState& st) const override {
    if (st.channels.empty() || st.channels[0].n < 2) return std::nullopt;
    const std::optional<VegasReport> rep = vegas_report(st);
    if (!rep) return std::nullopt;
    if (o_.weighted) return Headline{rep->combined_mean[0], rep->combined_std_error[0] * rep->error_scale};
    return Headline{st.channels[0].mean, st.channels[0].std_error() * rep->error_scale};
  }

  std::span<const std::string_view> counter_names() const override { return integration_counter_names(); }

  std::vector<std::string> warnings(const JobState& st) const override {
    std::vector<std::string> w;
    const auto r = vegas_report(st);
    if (r && r->inconsistent) {
      w.push_back(fmt::format(
          "VEGAS iterations disagree: chi^2/dof = {:.3g} over {} iterations (p = {:.2g}); the error bar is "
          "scaled by sqrt(chi^2/dof) = {:.3g}. The grid may have missed part of the integrand: use more "
          "samples per pass or more warm-up passes.",
          r->chi2_per_dof, r->used, r->p_value, r->error_scale));
    }
    for (std::string& c : integration_counter_warnings(st)) w.push_back(std::move(c));
    return w;
  }

 private:
  // The batch rows (xs[k * kB + i]) still hold the point.
  void record_fault(BlockResult& out, uint64_t sample, double value, uint32_t channel, const double* xs,
                    size_t i) const {
    out.counters.add(IntegrationCounter::nonfinite);
    if (out.fault) return;
    SampleFault f;
    f.sample_index = sample;
    f.channel = channel;
    f.value = value;
    std::string where;
    for (size_t k = 0; k < d_; ++k) {
      f.point.push_back(xs[k * kB + i]);
      where += fmt::format("{}x{} = {:.17g}", k ? ", " : "", k, f.point[k]);
    }
    f.message = fmt::format("the integrand{} is {} at {} (sample {})",
                            m_ > 1 ? fmt::format(" component {}", channel) : std::string(),
                            std::isnan(value) ? "NaN" : "infinite", where, sample);
    out.fault = std::move(f);
  }

  IntegrationProblem p_;
  VegasOptions o_;
  uint64_t key_;
  uint32_t d_, m_;
  double measure_ = 1.0;
  uint32_t ns_ = 1;  // VEGAS+: strata per axis
  uint64_t H_ = 1;   // hypercubes
};

}  // namespace

std::shared_ptr<const Kernel> make_vegas_kernel(IntegrationProblem p, VegasOptions o) {
  return std::make_shared<VegasKernel>(std::move(p), o);
}

std::optional<VegasReport> vegas_report(const JobState& st) {
  const std::optional<State> s = decode_state(st.kernel_state);
  if (!s) return std::nullopt;
  VegasReport r;
  r.bins = s->grid.nb;
  r.dimensions = s->grid.d;
  r.iterations = s->iterations;
  for (size_t k = 0; k < s->grid.d; ++k) {
    r.grid.emplace_back(s->grid.axis(k), s->grid.axis(k) + s->grid.nb + 1);
  }
  if (!s->hweights.empty()) {
    r.strata_per_axis = vegas_strata_per_axis(s->grid.d);
    r.hypercubes = s->hweights.size();
    const std::vector<uint64_t> c = allocation_bounds(s->hweights, r.hypercubes, kVegasRound);
    for (uint64_t h = 0; h < r.hypercubes; ++h) r.next_allocation.push_back(c[h + 1] - c[h]);
  }
  // chi^2 per component over the post-warm-up iterations; the worst one is reported.
  r.chi2 = std::numeric_limits<double>::quiet_NaN();
  r.chi2_per_dof = std::numeric_limits<double>::quiet_NaN();
  for (size_t k = 0; k < s->iterations.size(); ++k) r.used += s->iterations[k].warmup ? 0 : 1;
  r.combined_mean.assign(s->m, std::numeric_limits<double>::quiet_NaN());
  r.combined_std_error.assign(s->m, std::numeric_limits<double>::infinity());
  for (uint32_t c = 0; c < s->m; ++c) {
    double sw = 0.0, swm = 0.0;
    std::vector<std::pair<double, double>> pts;  // mean, variance of the mean (chi^2)
    // The estimate: pass k weighted by n_k / s_{k-1}^2, the previous pass's variance
    // per sample, which is known before pass k draws a sample. Weights fixed in
    // advance keep the weighted mean unbiased (unlike 1/se_k^2 from the pass's own
    // samples), and its variance sum w_k^2 se_k^2 / (sum w_k)^2 is estimated without bias.
    double cw = 0.0, cwm = 0.0, cw2v = 0.0;
    double prev_var = std::numeric_limits<double>::quiet_NaN();
    for (size_t k = 0; k < s->iterations.size(); ++k) {
      const Tally& t = s->components[k][c];
      const double var = t.n > 1 ? t.variance() : std::numeric_limits<double>::quiet_NaN();
      if (!s->iterations[k].warmup && t.n >= 2) {
        const double w = static_cast<double>(t.n) / (prev_var > 0.0 && std::isfinite(prev_var) ? prev_var : 1.0);
        cw += w;
        cwm += w * t.mean;
        cw2v += w * w * var / static_cast<double>(t.n);
        const double v = var / static_cast<double>(t.n);
        if (v > 0.0 && std::isfinite(v)) {
          pts.emplace_back(t.mean, v);
          sw += 1.0 / v;
          swm += t.mean / v;
        }
      }
      if (t.n > 1 && var > 0.0 && std::isfinite(var)) prev_var = var;
    }
    if (cw > 0.0) {
      r.combined_mean[c] = cwm / cw;
      r.combined_std_error[c] = std::sqrt(cw2v) / cw;
    }
    if (pts.size() < 2) continue;
    const double mw = swm / sw;
    double chi2 = 0.0;
    for (const auto& [m, v] : pts) chi2 += (m - mw) * (m - mw) / v;
    const double dof = static_cast<double>(pts.size() - 1);
    const double p = boost::math::cdf(boost::math::complement(boost::math::chi_squared(dof), chi2));
    if (std::isnan(r.chi2_per_dof) || p < r.p_value) {
      r.chi2 = chi2;
      r.chi2_per_dof = chi2 / dof;
      r.p_value = p;
    }
  }
  r.inconsistent = r.p_value < kVegasChi2Alarm;
  r.error_scale = r.inconsistent ? std::sqrt(std::max(1.0, r.chi2_per_dof)) : 1.0;
  return r;
}

void vegas_draw(const std::vector<std::vector<double>>& grid, uint64_t seed, uint64_t first, size_t n,
                std::vector<std::vector<double>>& points, std::vector<double>& pdf) {
  const uint64_t key = stream_key(seed, 0);
  const size_t d = grid.size();
  points.assign(d, std::vector<double>(n));
  std::vector<double> jac(n, 1.0);
  std::vector<uint32_t> bk(n);
  for (size_t k = 0; k < d; ++k) {
    const uint32_t nb = static_cast<uint32_t>(grid[k].size() - 1);
    std::vector<double> wd(nb);
    for (uint32_t j = 0; j < nb; ++j) wd[j] = grid[k][j + 1] - grid[k][j];
    map_axis(grid[k].data(), wd.data(), nb, key, first, n, static_cast<uint32_t>(k), 0.0, 1.0, points[k].data(),
             jac.data(), bk.data());
  }
  pdf.resize(n);
  for (size_t i = 0; i < n; ++i) pdf[i] = 1.0 / jac[i];
}

uint32_t vegas_strata_per_axis(size_t d) {
  // The largest s with s^d <= R / 4 (at least 2 samples per hypercube and room to adapt).
  uint32_t ns = 1;
  while (ipow(ns + 1, d) <= kVegasRound / 4) ++ns;
  return ns;
}

void vegas_plus_draw(const std::vector<std::vector<double>>& grid, uint32_t ns, const std::vector<uint64_t>& alloc,
                     uint64_t seed, uint64_t pass_start, uint64_t first, size_t n,
                     std::vector<std::vector<double>>& points, std::vector<double>& pdf) {
  const uint64_t key = stream_key(seed, 0);
  const size_t d = grid.size();
  const uint64_t H = alloc.size();
  std::vector<uint64_t> bounds(H + 1, 0);
  for (uint64_t h = 0; h < H; ++h) bounds[h + 1] = bounds[h] + alloc[h];
  if (bounds[H] != kVegasRound || ipow(ns, d) != H) throw std::invalid_argument("bad VEGAS+ allocation");
  std::vector<uint32_t> hc(n);
  std::vector<double> dens(n);
  for (size_t i = 0; i < n; ++i) {
    const uint64_t r = (first + i - pass_start) % kVegasRound;
    const uint64_t h = static_cast<uint64_t>(std::upper_bound(bounds.begin(), bounds.end(), r) - bounds.begin()) - 1;
    hc[i] = static_cast<uint32_t>(h);
    dens[i] = static_cast<double>(H) * static_cast<double>(alloc[h]) / static_cast<double>(kVegasRound);
  }
  points.assign(d, std::vector<double>(n));
  std::vector<double> jac(n, 1.0);
  std::vector<uint32_t> bk(n);
  uint64_t stride = 1;
  for (size_t k = 0; k < d; ++k) {
    const uint32_t nb = static_cast<uint32_t>(grid[k].size() - 1);
    std::vector<double> wd(nb);
    for (uint32_t j = 0; j < nb; ++j) wd[j] = grid[k][j + 1] - grid[k][j];
    map_axis_strat(grid[k].data(), wd.data(), nb, key, first, n, static_cast<uint32_t>(k), ns, stride, hc.data(),
                   0.0, 1.0, points[k].data(), jac.data(), bk.data());
    stride *= ns;
  }
  pdf.resize(n);
  for (size_t i = 0; i < n; ++i) pdf[i] = dens[i] / jac[i];
}

double vegas_grid_density(const std::vector<std::vector<double>>& grid, const double* x) {
  double p = 1.0;
  for (size_t k = 0; k < grid.size(); ++k) {
    const auto& e = grid[k];
    const size_t nb = e.size() - 1;
    size_t j = static_cast<size_t>(std::upper_bound(e.begin(), e.end(), x[k]) - e.begin());
    j = std::clamp<size_t>(j, 1, nb) - 1;
    const double w = e[j + 1] - e[j];
    p *= w > 0 ? 1.0 / (static_cast<double>(nb) * w) : 0.0;
  }
  return p;
}

}  // namespace tally
