// The hard regime of issue 31: the six Genz families at d in {8, 12, 16, 32} to 5 and 7
// digits (relative 5e-6, 5e-8), the peer study's protocol (genz_random_instance; every
// method stops by its own reported error at 95%, caps stated). tally runs
// `"estimator": {"type": "auto"}` (its time includes the pilot and the CBC
// construction); the peers are GSL plain/MISER/VEGAS and hcubature/pcubature, run
// interleaved per instance in this process. corner_peak stops at d = 20 (the built-in's
// limit); hcubature runs up to d = 16, pcubature to d = 12 (below). Success: |I_hat - I| <= target * |I|; coverage: |I_hat - I| <= the reported
// half-width. Options (environment; the full study is not small):
//   TALLY_HARD_DIMS=8,12,16,32  TALLY_HARD_TARGETS=5e-6,5e-8  TALLY_STUDY_INSTANCES=3
//   TALLY_HARD_SECONDS=10 (cap per method and instance)  TALLY_STUDY_FAMILIES=name,...
//   TALLY_HARD_METHODS=tally,gsl_plain,gsl_miser,gsl_vegas,hcubature,pcubature (and tally_cone,
//   tally_cone_lattice: the qmc and lattice estimators' cone rules, `"error": "cone"`, not in
//   the default set)
// SciPy's qmc_quad runs on the same instances afterwards: bench/peers/scipy_peer.py DIR --hard
// (reads DIR/hard_instances.json, written below; writes DIR/hard_scipy.csv).
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <map>
#include <sstream>

#include "bench/peers/cubature_peer.hpp"
#include "bench/peers/gsl_peers.hpp"
#include "bench/study/study_support.hpp"
#include "common/integrate/cone_rule.hpp"
#include "common/integrate/integration_job.hpp"
#include "common/integrate/lattice_rule.hpp"

namespace tally::study {

namespace {

template <class T>
std::vector<T> env_list(const char* name, std::vector<T> fallback) {
  const char* v = std::getenv(name);
  if (v == nullptr || *v == 0) return fallback;
  std::vector<T> out;
  std::stringstream ss(v);
  std::string item;
  while (std::getline(ss, item, ',')) {
    std::stringstream is(item);
    T x{};
    if (is >> x) out.push_back(x);
  }
  return out.empty() ? fallback : out;
}

// Every method's evaluation cap (the time cap binds first in practice).
constexpr uint64_t kMaxEvaluations = uint64_t{1} << 34;

bool method_selected(const std::vector<std::string>& methods, const std::string& m) {
  return std::find(methods.begin(), methods.end(), m) != methods.end();
}

struct Row {
  int reached = 0, covered = 0, runs = 0;
  std::vector<double> seconds;  // of the runs that reached the target
};

}  // namespace

void run_hard_study(const Options& o) {
  const auto dims = env_list<size_t>("TALLY_HARD_DIMS", {8, 12, 16, 32});
  const auto targets = env_list<double>("TALLY_HARD_TARGETS", {5e-6, 5e-8});
  const auto methods = env_list<std::string>(
      "TALLY_HARD_METHODS", {"tally", "gsl_plain", "gsl_miser", "gsl_vegas", "hcubature", "pcubature"});
  int instances = o.quick ? 1 : 3;
  if (const char* n = std::getenv("TALLY_STUDY_INSTANCES"); n != nullptr && std::atoi(n) > 0) instances = std::atoi(n);
  double cap = o.quick ? 1.0 : 10.0;
  if (const char* s = std::getenv("TALLY_HARD_SECONDS"); s != nullptr && std::atof(s) > 0) cap = std::atof(s);

  Csv csv(o.out / "hard.csv", {"family", "d", "target", "instance", "method", "estimate", "exact", "rel_error",
                               "reported_half_width", "seconds", "evaluations", "converged", "correct", "covered",
                               "note"});
  std::map<std::string, Row> summary;  // "family d target method"
  json inst = json::array();           // for bench/peers/scipy_peer.py --hard (SciPy's qmc_quad)
  if (method_selected(methods, "tally_cone_lattice")) {
    // The embedded lattice is built once per dimension and process (remembered), before
    // the runs: its construction is printed here and is not in the runs' times.
    for (size_t d : dims) {
      Stopwatch sw;
      embedded_lattice_rule_remembered(10, kLatticeConeLog2, std::vector<double>(d, kDefaultLatticeWeight));
      fmt::print("embedded lattice CBC, 2^10..2^{}, d = {}: {:.2f} s (once per process; not in the times below)\n",
                 kLatticeConeLog2, d, sw.seconds());
    }
  }
  for (size_t fi = 0; fi < genz_family_names().size(); ++fi) {
    const auto f = static_cast<GenzFamily>(fi);
    if (!family_selected(f)) continue;
    const std::string fam(genz_family_name(f));
    for (size_t d : dims) {
      if (f == GenzFamily::corner_peak && d > 20) continue;
      for (double target : targets) {
        peers::Target pt;
        pt.rel_half_width = target;
        pt.max_seconds = cap;
        pt.max_evaluations = kMaxEvaluations;
        for (int k = 0; k < instances; ++k) {
          const GenzParams p = genz_random_instance(f, d, static_cast<uint64_t>(k + 1));
          const double exact = genz_exact(p);
          json one = scipy_instance(p, k, exact);
          one["target"] = target;  // the hard regime has several
          inst.push_back(std::move(one));
          auto record = [&](const std::string& method, double est, double hw, double secs, uint64_t evals, bool conv,
                            const std::string& note) {
            const double err = std::fabs(est - exact);
            const bool correct = err <= target * std::fabs(exact);
            const bool covered = err <= hw;
            csv.row({fam, d, target, k, method, est, exact, err / std::fabs(exact), hw, secs, evals, conv ? 1 : 0,
                     correct ? 1 : 0, covered ? 1 : 0, note});
            if (!std::isfinite(est)) return;  // not run (the note says why)
            Row& r = summary[fmt::format("{} {} {:g} {}", fam, d, target, method)];
            ++r.runs;
            r.reached += conv && correct ? 1 : 0;
            r.covered += covered ? 1 : 0;
            if (conv && correct) r.seconds.push_back(secs);
          };
          if (method_selected(methods, "tally")) {
            const json stop = {{"rel_error", target}, {"confidence", 0.95}, {"time_budget_s", cap},
                               {"max_samples", uint64_t{1} << 30}};
            const JobRun r = run_spec(genz_spec(p, {{"type", "auto"}}, stop, static_cast<uint64_t>(k + 1)), o.threads);
            const ErrorSummary e = r.runner->error();
            const auto& plan = dynamic_cast<const IntegrationJob&>(*r.job).plan().estimator;
            record("tally", e.mean, e.abs_error, r.seconds, r.evaluations(),
                   r.runner->stop_reason() == StopReason::error_target,
                   fmt::format("{} auto->{}{} n={}", stop_reason_name(r.runner->stop_reason()), plan.type,
                               plan.periodize ? "/" + *plan.periodize : "", plan.points_per_sample.value_or(1)));
          }
          if (method_selected(methods, "tally_cone")) {
            // The cone rule (one randomization doubled to its Walsh-coefficient bound):
            // one block, so the time cap does not interrupt it; 2^24 points at most.
            const json stop = {{"rel_error", target}, {"max_samples", uint64_t{1} << 24}};
            const JobRun r = run_spec(genz_spec(p, {{"type", "qmc"}, {"error", "cone"}}, stop,
                                                static_cast<uint64_t>(k + 1)),
                                      o.threads);
            const ErrorSummary e = r.runner->error();
            record("tally_cone", e.mean, e.abs_error, r.seconds, r.evaluations(),
                   r.runner->stop_reason() == StopReason::error_target,
                   fmt::format("{} n={}", stop_reason_name(r.runner->stop_reason()), r.evaluations()));
          }
          if (method_selected(methods, "tally_cone_lattice")) {
            // The lattice form: the embedded lattice through the baker's transform, doubled to
            // its Fourier-coefficient bound; 2^20 points at most (the lattice's size).
            const json stop = {{"rel_error", target}, {"max_samples", uint64_t{1} << kLatticeConeLog2}};
            const JobRun r = run_spec(genz_spec(p, {{"type", "lattice"}, {"error", "cone"}}, stop,
                                                static_cast<uint64_t>(k + 1)),
                                      o.threads);
            const ErrorSummary e = r.runner->error();
            record("tally_cone_lattice", e.mean, e.abs_error, r.seconds, r.evaluations(),
                   r.runner->stop_reason() == StopReason::error_target,
                   fmt::format("{} n={}", stop_reason_name(r.runner->stop_reason()), r.evaluations()));
          }
          const peers::GenzScalar g = peer_integrand(p);
          for (peers::GslMethod m : {peers::GslMethod::plain, peers::GslMethod::miser, peers::GslMethod::vegas}) {
            if (!method_selected(methods, peers::gsl_method_name(m))) continue;
            const peers::PeerResult r = peers::run_gsl(m, g, pt, static_cast<unsigned long>(k + 1));
            record(peers::gsl_method_name(m), r.estimate, r.half_width, r.seconds, r.evaluations, r.converged, r.note);
          }
          for (peers::CubatureMethod m : {peers::CubatureMethod::h, peers::CubatureMethod::p}) {
            if (!method_selected(methods, peers::cubature_method_name(m))) continue;
            // One Genz-Malik region is 2^d + 2d^2 + 2d + 1 points and pcubature's first
            // Clenshaw-Curtis level 3^d: beyond d = 16 (h) and d = 12 (p) the first call
            // cannot stop at the time cap (checked between calls), so they are not run.
            const size_t max_d = m == peers::CubatureMethod::h ? 16 : 12;
            if (d > max_d) {
              record(peers::cubature_method_name(m), NAN, 0.0, 0.0, 0, false, fmt::format("not run: d > {}", max_d));
              continue;
            }
            const peers::PeerResult r = peers::run_cubature(m, g, pt);
            record(peers::cubature_method_name(m), r.estimate, r.half_width, r.seconds, r.evaluations, r.converged,
                   r.note);
          }
        }
      }
    }
  }
  std::ofstream(o.out / "hard_instances.json")
      << json{{"max_seconds", cap}, {"max_evaluations", kMaxEvaluations}, {"instances", inst}}.dump(1);
  // The first figures: per family, dimension, target and method, the fraction that reached
  // the target (converged by its own rule and correct), the median time of those, and the
  // fraction whose reported half-width covered the error.
  for (auto& [key, r] : summary) {
    std::sort(r.seconds.begin(), r.seconds.end());
    const std::string med = r.seconds.empty() ? "-" : fmt::format("{:.3g} s", r.seconds[r.seconds.size() / 2]);
    log(fmt::format("hard {}: reached {}/{}, median {}, covered {}/{}", key, r.reached, r.runs, med, r.covered,
                    r.runs));
  }
}

}  // namespace tally::study
