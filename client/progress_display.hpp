#pragma once
// What `tally watch` prints for each progress event: a redrawn bar on stderr when
// it is a terminal (colour unless NO_COLOR is set), plain lines otherwise.
#include <cstdio>
#include <nlohmann/json.hpp>
#include <string>

#include "client/sparkline.hpp"

namespace tally {

struct DisplayOptions {
  bool tty = false;
  bool color = false;
  int width = 28;  // bar cells
};

DisplayOptions detect_display(std::FILE* out);

// `mean ± stderr (95% CI [lo, hi])` from a progress object.
std::string estimate_text(const nlohmann::json& progress);
// Fraction done in [0, 1] from the progress and the job's stop rule; < 0 if unknown.
double progress_fraction(const nlohmann::json& progress, const nlohmann::json& stop_rule);
std::string format_duration(double seconds);
std::string format_count(double n);  // 1.2k, 3.4M, 5.6G

class ProgressDisplay {
 public:
  ProgressDisplay(std::FILE* out, DisplayOptions options) : out_(out), opt_(options) {}
  void set_stop_rule(nlohmann::json rule) { rule_ = std::move(rule); }
  void progress(const nlohmann::json& p);
  void message(const std::string& text);  // on its own line
  void finish();                          // ends a bar line

 private:
  std::FILE* out_;
  DisplayOptions opt_;
  nlohmann::json rule_ = nlohmann::json::object();
  bool bar_open_ = false;
  Sparkline spark_;  // error over compute time (terminal only)
};

}  // namespace tally
