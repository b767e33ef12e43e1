#pragma once
// Lines of the Prometheus text exposition format (0.0.4) for GET /metrics: every metric
// family starts with its HELP and TYPE lines; most here have one unlabelled sample.
#include <fmt/format.h>

#include <string>
#include <string_view>

namespace tally {

// "# HELP <name> <help>\n# TYPE <name> <type>\n" (type: gauge, counter, histogram).
inline void prom_header(std::string& o, std::string_view name, std::string_view type, std::string_view help) {
  o += fmt::format("# HELP {} {}\n# TYPE {} {}\n", name, help, name, type);
}

// A family of one unlabelled sample: its header, then "<name> <value>\n".
template <class T>
void prom_metric(std::string& o, std::string_view name, std::string_view type, std::string_view help, const T& value) {
  prom_header(o, name, type, help);
  o += fmt::format("{} {}\n", name, value);
}

}  // namespace tally
