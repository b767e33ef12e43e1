// Samples per CPU-second of the lecture's unit-disk integral: tally's built-in
// integrand and the same integrand as a muParser-syntax expression, both with full
// statistics (Welford/Chan tallies, tail tracking, checks for NaN), against GSL's
// gsl_monte_plain_integrate in the same run. Prints figures; not a timed test.
//
//   build/bench/integrate_bench [samples=16777216] [repeats=5]
#include <gsl/gsl_monte_plain.h>
#include <gsl/gsl_rng.h>
#include <time.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <vector>

#include "common/engine/pass_loop.hpp"
#include "common/protocol/job_kinds.hpp"

namespace {

double cpu_seconds() {
  timespec ts{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
}
double wall_seconds() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
}

struct Rate {
  double per_cpu_s = 0, per_wall_s = 0, mean = 0, err = 0;
};

Rate run_tally(const nlohmann::json& integrand, uint64_t n, unsigned threads) {
  nlohmann::json spec = {{"kind", "integrate"},
                         {"seed", 1},
                         {"integrand", integrand},
                         {"domain", {{"type", "box"}, {"lower", {-1, -1}}, {"upper", {1, 1}}}},
                         {"stop", {{"max_samples", n}}}};
  auto job = tally::compile_job(spec, tally::JobLimits{});
  tally::JobRunner r(job->kernel(), job->stop_rule(), tally::JobCaps{});
  const double c0 = cpu_seconds(), w0 = wall_seconds();
  tally::run_local(r, threads);
  const double c1 = cpu_seconds(), w1 = wall_seconds();
  const auto e = r.estimate(0);
  return {static_cast<double>(n) / (c1 - c0), static_cast<double>(n) / (w1 - w0), e.mean, e.std_error};
}

double disk(double* x, size_t, void*) { return (x[0] * x[0] + x[1] * x[1] < 1.0) ? 1.0 : 0.0; }

Rate run_gsl(uint64_t n) {
  gsl_monte_function f{&disk, 2, nullptr};
  double lo[2] = {-1, -1}, hi[2] = {1, 1};
  gsl_rng* rng = gsl_rng_alloc(gsl_rng_default);
  gsl_monte_plain_state* s = gsl_monte_plain_alloc(2);
  double result = 0, abserr = 0;
  const double c0 = cpu_seconds(), w0 = wall_seconds();
  gsl_monte_plain_integrate(&f, lo, hi, 2, n, rng, s, &result, &abserr);
  const double c1 = cpu_seconds(), w1 = wall_seconds();
  gsl_monte_plain_free(s);
  gsl_rng_free(rng);
  return {static_cast<double>(n) / (c1 - c0), static_cast<double>(n) / (w1 - w0), result, abserr};
}

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

}  // namespace

int main(int argc, char** argv) {
  const uint64_t n = argc > 1 ? std::strtoull(argv[1], nullptr, 10) : (1u << 24);
  const int repeats = argc > 2 ? std::atoi(argv[2]) : 5;
  const nlohmann::json builtin = {{"builtin", "unit_disk"}};
  const nlohmann::json expr = {{"expression", "x0*x0 + x1*x1 < 1 ? 1 : 0"}};
  std::vector<double> b, e, g, b2w, b1w;
  Rate lb, le, lg;
  // Interleaved repetitions: every method sees the same background load.
  for (int i = 0; i < repeats; ++i) {
    lg = run_gsl(n);
    g.push_back(lg.per_cpu_s);
    lb = run_tally(builtin, n, 1);
    b.push_back(lb.per_cpu_s);
    b1w.push_back(lb.per_wall_s);
    le = run_tally(expr, n, 1);
    e.push_back(le.per_cpu_s);
    b2w.push_back(run_tally(builtin, n, 2).per_wall_s);
  }
  const double mb = median(b), me = median(e), mg = median(g);
  std::printf("unit-disk integral over [-1,1]^2, %llu samples per run, median of %d interleaved runs\n",
              static_cast<unsigned long long>(n), repeats);
  std::printf("  %-34s %8.1f M samples/CPU-s   estimate %.6f ± %.2g\n", "GSL gsl_monte_plain_integrate", mg / 1e6, lg.mean, lg.err);
  std::printf("  %-34s %8.1f M samples/CPU-s   estimate %.6f ± %.2g\n", "tally built-in (1 thread)", mb / 1e6, lb.mean, lb.err);
  std::printf("  %-34s %8.1f M samples/CPU-s   estimate %.6f ± %.2g\n", "tally expression (1 thread)", me / 1e6, le.mean, le.err);
  std::printf("ratio built-in / GSL plain:   %.2f   (goal >= 3)\n", mb / mg);
  std::printf("ratio expression / GSL plain: %.2f   (goal >= 1)\n", me / mg);
  std::printf("scaling 2 threads / 1 thread (wall): %.2f\n", median(b2w) / median(b1w));
  return 0;
}
