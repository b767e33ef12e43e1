#include "client/sparkline.hpp"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <string_view>

namespace tally {

namespace {
constexpr const char* kBlocks[8] = {"▁", "▂", "▃", "▄", "▅", "▆", "▇", "█"};
constexpr std::string_view kAscii = " .:-=+*#";
}  // namespace

void Sparkline::add(double t, double value) {
  if (!std::isfinite(t) || !std::isfinite(value) || value <= 0) return;
  if (!points_.empty() && t < points_.back().t) return;  // out of order: ignore
  points_.push_back({t, value});
  if (points_.size() > max_points_) {
    // Keep the first and last, thin the rest by half: memory stays bounded on long runs.
    std::vector<Point> kept;
    kept.reserve(points_.size() / 2 + 2);
    for (size_t i = 0; i + 1 < points_.size(); i += 2) kept.push_back(points_[i]);
    kept.push_back(points_.back());
    points_.swap(kept);
  }
}

std::string Sparkline::render(size_t cells, bool ascii) const {
  if (points_.size() < 2 || cells == 0) return {};
  const double t0 = points_.front().t, t1 = points_.back().t;
  // Cell i shows the last value observed at or before its right edge in time, so
  // the chart reads left to right like a clock even when events come unevenly.
  std::vector<double> v(cells);
  size_t j = 0;
  for (size_t i = 0; i < cells; ++i) {
    const double edge = t1 > t0 ? t0 + (t1 - t0) * static_cast<double>(i + 1) / static_cast<double>(cells)
                                : t1;
    while (j + 1 < points_.size() && points_[j + 1].t <= edge) ++j;
    v[i] = points_[j].v;
  }
  v.back() = points_.back().v;
  double lo = v[0], hi = v[0];
  for (double x : v) {
    lo = std::min(lo, x);
    hi = std::max(hi, x);
  }
  const double llo = std::log(lo), lhi = std::log(hi);
  std::string out;
  for (double x : v) {
    int level = 3;  // a flat series sits mid-height
    if (lhi > llo) level = static_cast<int>(std::lround(7.0 * (std::log(x) - llo) / (lhi - llo)));
    level = std::clamp(level, 0, 7);
    if (ascii) {
      out.push_back(kAscii[static_cast<size_t>(level)]);
    } else {
      out += kBlocks[level];
    }
  }
  return out;
}

bool terminal_is_utf8() {
  for (const char* var : {"LC_ALL", "LC_CTYPE", "LANG"}) {
    const char* v = std::getenv(var);
    if (v && *v) {
      std::string s(v);
      std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
      return s.find("utf-8") != std::string::npos || s.find("utf8") != std::string::npos;
    }
  }
  return false;
}

}  // namespace tally
