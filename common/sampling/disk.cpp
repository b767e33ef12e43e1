#include "common/sampling/disk.hpp"

#include <cmath>

namespace tally {

Vec2 sample_uniform_disk_polar(Vec2 u) {
  const double r = std::sqrt(u.x);
  const double theta = 2.0 * kPi * u.y;
  return {r * std::cos(theta), r * std::sin(theta)};
}

Vec2 invert_uniform_disk_polar(Vec2 p) {
  return {clamp_unit(p.x * p.x + p.y * p.y), angle_to_unit(p.y, p.x)};
}

DiskPolar sample_uniform_disk_concentric_polar(Vec2 u) {
  const double a = 2.0 * u.x - 1.0, b = 2.0 * u.y - 1.0;
  if (a == 0 && b == 0) return {0.0, 0.0};
  // Shirley-Chiu: the square ring max(|a|, |b|) = r maps to the circle of radius r.
  if (std::abs(a) > std::abs(b)) {
    const double theta = kPiOver4 * (b / a);
    return a > 0 ? DiskPolar{a, theta} : DiskPolar{-a, theta + kPi};
  }
  const double theta = kPiOver2 - kPiOver4 * (a / b);
  return b > 0 ? DiskPolar{b, theta} : DiskPolar{-b, theta + kPi};
}

Vec2 sample_uniform_disk_concentric(Vec2 u) {
  const DiskPolar p = sample_uniform_disk_concentric_polar(u);
  return {p.r * std::cos(p.theta), p.r * std::sin(p.theta)};
}

Vec2 invert_uniform_disk_concentric(Vec2 p) {
  const double r = std::sqrt(p.x * p.x + p.y * p.y);
  double phi = std::atan2(p.y, p.x);      // (-pi, pi]
  if (phi < -kPiOver4) phi += 2.0 * kPi;  // now [-pi/4, 7 pi/4): one branch per wedge
  double a, b;
  if (phi < kPiOver4) {  // right wedge: r = a > 0, theta = pi/4 * b / a
    a = r;
    b = r * phi / kPiOver4;
  } else if (phi < 3.0 * kPiOver4) {  // top wedge: r = b > 0, theta = pi/2 - pi/4 * a / b
    b = r;
    a = r * (kPiOver2 - phi) / kPiOver4;
  } else if (phi < 5.0 * kPiOver4) {  // left wedge: r = a < 0, angle = theta + pi
    a = -r;
    b = -r * (phi - kPi) / kPiOver4;
  } else {  // bottom wedge: r = b < 0, angle = theta + pi
    b = -r;
    a = -r * (3.0 * kPiOver2 - phi) / kPiOver4;
  }
  return {clamp_unit(0.5 * (a + 1.0)), clamp_unit(0.5 * (b + 1.0))};
}

std::optional<Vec2> sample_uniform_disk_rejection(SampleRng& rng, std::uint64_t max_attempts,
                                                  RejectionStats& stats) {
  return rejection_sample(rng, max_attempts, stats, [](SampleRng& r) -> std::optional<Vec2> {
    const double x = 1.0 - 2.0 * r.next();
    const double y = 1.0 - 2.0 * r.next();
    if (x * x + y * y > 1.0) return std::nullopt;
    return Vec2{x, y};
  });
}

Vec2 sample_direction_2d(double u) {
  const double theta = 2.0 * kPi * u;
  return {std::cos(theta), std::sin(theta)};
}

double invert_direction_2d(Vec2 d) {
  return angle_to_unit(d.y, d.x);
}

std::optional<Vec2> sample_direction_2d_rejection(SampleRng& rng, std::uint64_t max_attempts,
                                                  RejectionStats& stats) {
  return rejection_sample(rng, max_attempts, stats, [](SampleRng& r) -> std::optional<Vec2> {
    const double x = 1.0 - 2.0 * r.next();
    const double y = 1.0 - 2.0 * r.next();
    const double r2 = x * x + y * y;
    if (r2 > 1.0 || r2 == 0.0) return std::nullopt;  // outside the disk, or no direction
    const double len = std::sqrt(r2);
    return Vec2{x / len, y / len};
  });
}

}  // namespace tally
