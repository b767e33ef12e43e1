#include "common/stats/confidence.hpp"

#include <boost/math/distributions/normal.hpp>
#include <boost/math/distributions/students_t.hpp>
#include <cmath>
#include <limits>

namespace tally {

double critical_value(double confidence, uint64_t n) {
  const double tail = 0.5 * (1.0 - confidence);
  if (n < 2) return std::numeric_limits<double>::infinity();
  if (n > 100000) {
    return boost::math::quantile(boost::math::complement(boost::math::normal(), tail));
  }
  const boost::math::students_t dist(static_cast<double>(n - 1));
  return boost::math::quantile(boost::math::complement(dist, tail));
}

Interval confidence_interval(const Tally& t, double confidence) {
  const double z = critical_value(confidence, t.n);
  const double h = z * t.std_error();
  return {t.mean - h, t.mean + h};
}

double samples_for_half_width(double sigma, double half_width, double confidence) {
  const double z = critical_value(confidence, 1000000);
  if (!(half_width > 0.0)) return std::numeric_limits<double>::infinity();
  const double r = z * sigma / half_width;
  return r * r;
}

}  // namespace tally
