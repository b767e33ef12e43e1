// tally-study: runs the accuracy-vs-time study's sections and writes their CSVs.
//   tally-study [--out DIR] [--quick] [--threads N] [section ...]
// Sections: quadrature variance disk lighting rqmc peers (default: all); hard (issue 31's
// regime: d 8-32, 5 and 7 digits) runs only when named.
#include <fmt/format.h>

#include <algorithm>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <functional>
#include <map>

#include "bench/study/study_support.hpp"

int main(int argc, char** argv) {
  using namespace tally::study;
  const std::map<std::string, std::function<void(const Options&)>> sections = {
      {"quadrature", run_quadrature_study}, {"variance", run_variance_study}, {"disk", run_disk_study},
      {"lighting", run_lighting_study},     {"rqmc", run_rqmc_study},         {"peers", run_peer_study}, {"peers-tune", run_peer_tuning}, {"vegas-tune", run_vegas_tuning}, {"eta", run_eta_study}, {"hard", run_hard_study}};
  const std::vector<std::string> order = {"quadrature", "variance", "disk", "rqmc", "eta", "lighting", "peers"};
  Options o;
  std::vector<std::string> chosen;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--out" && i + 1 < argc) {
      o.out = argv[++i];
    } else if (a == "--quick") {
      o.quick = true;
    } else if (a == "--threads" && i + 1 < argc) {
      o.threads = static_cast<unsigned>(std::atoi(argv[++i]));
    } else if (sections.count(a) != 0) {
      chosen.push_back(a);
    } else {
      std::vector<std::string> on_demand;  // run only when named
      for (const auto& [name, run] : sections) {
        if (std::find(order.begin(), order.end(), name) == order.end()) on_demand.push_back(name);
      }
      fmt::print(stderr,
                 "usage: tally-study [--out DIR] [--quick] [--threads N] [{}]...\n"
                 "  default: all of {}; run only when named: {}\n",
                 fmt::join(order, "|"), fmt::join(order, " "), fmt::join(on_demand, " "));
      return 2;
    }
  }
  if (chosen.empty()) chosen = order;
  try {
    for (const std::string& s : chosen) {
      Stopwatch sw;
      log("section " + s);
      sections.at(s)(o);
      log(fmt::format("section {} done in {:.1f} s", s, sw.seconds()));
    }
  } catch (const std::exception& e) {
    fmt::print(stderr, "tally-study: {}\n", e.what());
    return 1;
  }
  return 0;
}
