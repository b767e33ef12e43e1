#include "client/progress_display.hpp"

#include <fmt/format.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <cstdlib>

namespace tally {

using nlohmann::json;

namespace {
double num(const json& j, const char* key, double fallback = std::numeric_limits<double>::quiet_NaN()) {
  const auto it = j.find(key);
  return it != j.end() && it->is_number() ? it->get<double>() : fallback;
}
}  // namespace

DisplayOptions detect_display(std::FILE* out) {
  DisplayOptions o;
  o.tty = ::isatty(::fileno(out)) == 1;
  const char* no_color = std::getenv("NO_COLOR");
  const char* term = std::getenv("TERM");
  o.color = o.tty && !(no_color && *no_color) && !(term && std::string_view(term) == "dumb");
  return o;
}

std::string format_duration(double s) {
  if (!std::isfinite(s)) return "?";
  if (s < 1) return fmt::format("{:.2f}s", s);
  if (s < 60) return fmt::format("{:.1f}s", s);
  if (s < 3600) return fmt::format("{}m{:02}s", static_cast<int>(s / 60), static_cast<int>(s) % 60);
  return fmt::format("{}h{:02}m", static_cast<int>(s / 3600), static_cast<int>(s / 60) % 60);
}

std::string format_count(double n) {
  if (!std::isfinite(n)) return "?";
  if (n < 1e3) return fmt::format("{:.0f}", n);
  if (n < 1e6) return fmt::format("{:.1f}k", n / 1e3);
  if (n < 1e9) return fmt::format("{:.1f}M", n / 1e6);
  return fmt::format("{:.2f}G", n / 1e9);
}

std::string estimate_text(const json& p) {
  const json e = p.value("estimate", json::object());
  const double mean = num(e, "mean"), se = num(e, "std_error");
  if (!std::isfinite(mean)) return "(no estimate yet)";
  const json ci = e.value("ci", json::array());
  const double conf = num(e, "confidence", 0.95) * 100;
  if (ci.size() == 2 && ci[0].is_number() && ci[1].is_number() && std::isfinite(se)) {
    return fmt::format("{:.10g} ± {:.3g} ({:g}% CI [{:.10g}, {:.10g}])", mean, se, conf, ci[0].get<double>(),
                       ci[1].get<double>());
  }
  return fmt::format("{:.10g}", mean);
}

double progress_fraction(const json& p, const json& rule) {
  double f = -1;
  const double samples = num(p, "samples", 0);
  if (const auto pr = p.find("prediction"); pr != p.end() && pr->is_object()) {
    const double need = num(*pr, "samples_needed");
    if (std::isfinite(need) && need > 0) f = std::max(f, samples / need);
  }
  const double max_samples = num(rule, "max_samples");
  if (std::isfinite(max_samples) && max_samples > 0) f = std::max(f, samples / max_samples);
  const double budget = num(rule, "time_budget_s");
  if (std::isfinite(budget) && budget > 0) f = std::max(f, num(p, "compute_seconds", 0) / budget);
  return f < 0 ? -1 : std::min(1.0, f);
}

void ProgressDisplay::progress(const json& p) {
  const double frac = progress_fraction(p, rule_);
  const double rate = num(p, "samples_per_second", 0);
  const double eta = num(p, "eta_seconds");
  const std::string est = estimate_text(p);
  const std::string tail = fmt::format("{} samples  {}/s  ETA {}", format_count(num(p, "samples", 0)),
                                       format_count(rate), std::isfinite(eta) ? format_duration(eta) : "?");
  if (!opt_.tty) {
    fmt::print(out_, "pass {}  {}  {}{}\n", p.value("pass", p.value("passes", 0)), est, tail,
               frac >= 0 ? fmt::format("  {:.0f}%", 100 * frac) : "");
    std::fflush(out_);
    return;
  }
  // The running error (CI half-width) and its history as a sparkline.
  const json err = p.value("error", json::object());
  const double abs_err = err.is_object() ? num(err, "abs") : std::nan("");
  spark_.add(num(p, "compute_seconds", 0), abs_err);
  const std::string spark = spark_.render(12, !terminal_is_utf8());
  const std::string err_text = std::isfinite(abs_err) ? fmt::format("  err {:.3g} {}", abs_err, spark) : "";
  std::string bar;
  if (frac >= 0) {
    const int fill = static_cast<int>(std::round(frac * opt_.width));
    bar = "[" + std::string(static_cast<size_t>(fill), '#') + std::string(static_cast<size_t>(opt_.width - fill), '.') +
          fmt::format("] {:3.0f}%  ", 100 * frac);
  }
  if (opt_.color) {
    fmt::print(out_, "\r\x1b[2K\x1b[36m{}\x1b[0m\x1b[1m{}\x1b[0m  \x1b[2m{}\x1b[0m\x1b[33m{}\x1b[0m", bar, est, tail, err_text);
  } else {
    fmt::print(out_, "\r\x1b[2K{}{}  {}{}", bar, est, tail, err_text);
  }
  std::fflush(out_);
  bar_open_ = true;
}

void ProgressDisplay::message(const std::string& text) {
  finish();
  fmt::print(out_, "{}\n", text);
  std::fflush(out_);
}

void ProgressDisplay::finish() {
  if (bar_open_) {
    fmt::print(out_, "\n");
    bar_open_ = false;
  }
}

}  // namespace tally
