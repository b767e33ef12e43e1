// Peers side by side on the Genz suite with Cuba's protocol (genz_random_instance:
// u ~ U(0,1)^d, a = w h / sum(w)): tally against GSL plain, MISER and VEGAS, run
// interleaved per instance in this process so their time ratios share one machine
// state. Every method stops by its own reported error: 95% half-width <= 5e-4 |I|.
// Success ("3 correct digits"): |I_hat - I| <= 5e-4 |I|. Coverage: |I_hat - I| <=
// the reported 95% half-width. SciPy's qmc_quad runs on the same instances from
// bench/peers/scipy_peer.py (instances.json below).
#include <fmt/format.h>

#include <cmath>
#include <fstream>

#include "bench/peers/gsl_peers.hpp"
#include "bench/study/study_support.hpp"

namespace tally::study {

namespace {

constexpr double kRelTarget = 5e-4;

// tally's estimator per family, as a user would pick it: randomized QMC for every
// family (all six are functions of bounded variation on the cube in the sense that
// matters here; the discontinuous one's jumps are axis-aligned, which scrambled
// Sobol nets resolve well). Points per randomization: 4096, so that the default 16
// randomizations give a t interval with 15 degrees of freedom.
json tally_estimator(GenzFamily) { return {{"type", "qmc"}, {"points", 4096}}; }

}  // namespace

void run_peer_study(const Options& o) {
  const std::vector<size_t> dims = o.quick ? std::vector<size_t>{2, 4} : std::vector<size_t>{2, 4, 6};
  const int instances = o.quick ? 3 : 20;
  peers::Target target;
  target.rel_half_width = kRelTarget;
  target.max_seconds = o.quick ? 0.2 : 1.0;
  target.max_evaluations = uint64_t{1} << 25;

  Csv csv(o.out / "peers.csv", {"family", "d", "instance", "method", "estimate", "exact", "rel_error",
                                 "reported_half_width", "seconds", "evaluations", "converged", "correct", "covered",
                                 "note"});
  json inst = json::array();
  for (size_t fi = 0; fi < genz_family_names().size(); ++fi) {
    const auto f = static_cast<GenzFamily>(fi);
    const std::string fam(genz_family_name(f));
    for (size_t d : dims) {
      for (int k = 0; k < instances; ++k) {
        const GenzParams p = genz_random_instance(f, d, static_cast<uint64_t>(k + 1));
        const double exact = genz_exact(p);
        inst.push_back({{"family", fam}, {"family_index", fi}, {"d", d}, {"instance", k}, {"a", p.a}, {"u", p.u},
                        {"exact", exact}});
        auto record = [&](const std::string& method, double est, double hw, double secs, uint64_t evals, bool conv,
                          const std::string& note) {
          const double err = std::fabs(est - exact);
          csv.row({fam, d, k, method, est, exact, err / std::fabs(exact), hw, secs, evals, conv ? 1 : 0,
                   err <= kRelTarget * std::fabs(exact) ? 1 : 0, err <= hw ? 1 : 0, note});
        };
        {
          // Same caps as the peers: the samples cap counts randomizations of 4096 points.
          const json est = tally_estimator(f);
          const uint64_t per = est.value("points", uint64_t{1});
          const json stop = {{"rel_error", kRelTarget},
                             {"confidence", 0.95},
                             {"time_budget_s", target.max_seconds},
                             {"max_samples", target.max_evaluations / per}};
          const JobRun r = run_spec(genz_spec(p, est, stop, static_cast<uint64_t>(k + 1)), 1);
          const ErrorSummary e = r.runner->error();
          record("tally", e.mean, e.abs_error, r.seconds, r.evaluations(),
                 r.runner->stop_reason() == StopReason::error_target,
                 std::string(stop_reason_name(r.runner->stop_reason())));
        }
        peers::GenzScalar g;
        g.family = static_cast<int>(fi);
        g.d = d;
        g.a = p.a.data();
        g.u = p.u.data();
        for (peers::GslMethod m : {peers::GslMethod::plain, peers::GslMethod::miser, peers::GslMethod::vegas}) {
          const peers::PeerResult r = peers::run_gsl(m, g, target, static_cast<unsigned long>(k + 1));
          record(peers::gsl_method_name(m), r.estimate, r.half_width, r.seconds, r.evaluations, r.converged, r.note);
        }
      }
      log(fmt::format("peers {} d={} done", fam, d));
    }
  }
  std::ofstream(o.out / "instances.json") << json{{"rel_target", kRelTarget},
                                                  {"max_seconds", target.max_seconds},
                                                  {"max_evaluations", target.max_evaluations},
                                                  {"instances", inst}}
                                                 .dump(1);
}

}  // namespace tally::study
