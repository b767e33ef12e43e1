#include "bench/study/study_support.hpp"

#include <fmt/format.h>

#include <cmath>
#include <cstdlib>
#include <stdexcept>

#include "common/engine/pass_loop.hpp"
#include "common/protocol/job_kinds.hpp"

namespace tally::study {

JobRun run_spec(const json& spec, unsigned threads) {
  Stopwatch sw;
  JobRun r;
  r.job = compile_job(spec, JobLimits{});
  r.runner = std::make_unique<JobRunner>(r.job->kernel(), r.job->stop_rule(), JobCaps{});
  run_local(*r.runner, threads);
  r.seconds = sw.seconds();
  return r;
}

JobRun run_kernel(std::shared_ptr<const Kernel> kernel, const StopRule& rule, unsigned threads) {
  Stopwatch sw;
  JobRun r;
  r.runner = std::make_unique<JobRunner>(std::move(kernel), rule, JobCaps{});
  run_local(*r.runner, threads);
  r.seconds = sw.seconds();
  return r;
}

SeedStats over_seeds(const std::function<json(uint64_t seed)>& spec_of, double exact, int seeds,
                     unsigned threads) {
  SeedStats s;
  s.seeds = seeds;
  Tally est;
  double se2 = 0.0, sq = 0.0;
  for (int k = 0; k < seeds; ++k) {
    const JobRun r = run_spec(spec_of(static_cast<uint64_t>(k + 1)), threads);
    const Estimate e = r.runner->estimate(0);
    est.add(e.mean);
    sq += (e.mean - exact) * (e.mean - exact);
    se2 += e.std_error * e.std_error;
    s.seconds += r.compute_seconds();
    s.evaluations += static_cast<double>(r.evaluations());
  }
  s.mean = est.mean;
  s.variance = est.variance();
  s.rmse = std::sqrt(sq / seeds);
  s.reported_var = se2 / seeds;
  s.seconds /= seeds;
  s.evaluations /= seeds;
  return s;
}

json scipy_instance(const GenzParams& p, int instance, double exact) {
  return {{"family", std::string(genz_family_name(p.family))},
          {"family_index", static_cast<int>(p.family)},
          {"d", p.a.size()},
          {"instance", instance},
          {"a", p.a},
          {"u", p.u},
          {"exact", exact}};
}

json genz_spec(const GenzParams& p, const json& estimator, const json& stop, uint64_t seed) {
  return {{"kind", "integrate"},
          {"seed", seed},
          {"integrand",
           {{"builtin", "genz"}, {"family", std::string(genz_family_name(p.family))}, {"a", p.a}, {"u", p.u}}},
          {"estimator", estimator},
          {"stop", stop}};
}

Csv::Csv(const std::filesystem::path& path, const std::vector<std::string>& columns) : columns_(columns.size()) {
  std::filesystem::create_directories(path.parent_path());
  f_ = std::fopen(path.c_str(), "w");
  if (f_ == nullptr) throw std::runtime_error("cannot write " + path.string());
  for (size_t i = 0; i < columns.size(); ++i) std::fprintf(f_, "%s%s", i ? "," : "", columns[i].c_str());
  std::fprintf(f_, "\n");
}

Csv::~Csv() {
  if (f_ != nullptr) std::fclose(f_);
}

void Csv::row(const std::vector<json>& cells) {
  if (cells.size() != columns_) {
    throw std::logic_error(fmt::format("csv row has {} cells, header {}", cells.size(), columns_));
  }
  for (size_t i = 0; i < cells.size(); ++i) {
    const json& c = cells[i];
    std::string s;
    if (c.is_string()) {
      s = c.get<std::string>();
    } else if (c.is_number_float()) {
      s = fmt::format("{:.17g}", c.get<double>());
    } else if (c.is_null()) {
      s = "";
    } else {
      s = c.dump();
    }
    std::fprintf(f_, "%s%s", i ? "," : "", s.c_str());
  }
  std::fprintf(f_, "\n");
  std::fflush(f_);
}

void log(const std::string& line) {
  std::fprintf(stderr, "[study] %s\n", line.c_str());
}

peers::GenzScalar peer_integrand(const GenzParams& p) {
  peers::GenzScalar g;
  g.family = static_cast<int>(p.family);
  g.d = p.a.size();
  g.a = p.a.data();
  g.u = p.u.data();
  return g;
}

bool family_selected(GenzFamily f) {
  const char* env = std::getenv("TALLY_STUDY_FAMILIES");
  if (env == nullptr || *env == 0) return true;
  const std::string list = std::string(",") + env + ",";
  return list.find(fmt::format(",{},", genz_family_name(f))) != std::string::npos;
}

}  // namespace tally::study
