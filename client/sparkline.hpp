#pragma once
// A one-line chart of a job's error over time for `tally watch`: the running error
// (CI half-width) of each progress event, resampled to a few cells and drawn with
// the eight block characters ▁▂▃▄▅▆▇█ on a log scale (errors span decades).
// Plain ASCII (" .:-=+*#") when the terminal cannot show UTF-8.
#include <cstddef>
#include <string>
#include <vector>

namespace tally {

class Sparkline {
 public:
  explicit Sparkline(size_t max_points = 512) : max_points_(max_points < 2 ? 2 : max_points) {}

  // One observation at time t (seconds); non-finite or non-positive values are skipped.
  void add(double t, double value);
  size_t size() const { return points_.size(); }
  void clear() { points_.clear(); }

  // `cells` characters, oldest at the left; the newest cell always holds the newest
  // value. Empty when fewer than two points are known.
  std::string render(size_t cells, bool ascii = false) const;

 private:
  struct Point {
    double t, v;
  };
  std::vector<Point> points_;
  size_t max_points_;
};

// True when the locale's character set is UTF-8 (LC_ALL / LC_CTYPE / LANG).
bool terminal_is_utf8();

}  // namespace tally
