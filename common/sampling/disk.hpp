#pragma once
// Uniform sampling of the unit disk and of 2-D directions. Every warp has a pdf and,
// where it is a bijection, an inverse (for round-trip tests and for QMC/stratified
// points that must keep their structure).
#include <cstdint>
#include <optional>

#include "common/math/vec3.hpp"
#include "common/rng/counter_rng.hpp"
#include "common/sampling/rejection.hpp"
#include "common/sampling/safe_math.hpp"

namespace tally {

// Density of every uniform disk sampler below, w.r.t. area.
constexpr double uniform_disk_pdf() {
  return kInvPi;
}

// Polar map: r = sqrt(u.x) (area grows with r^2, so r = u.x would crowd the centre),
// theta = 2 pi u.y.
Vec2 sample_uniform_disk_polar(Vec2 u);
Vec2 invert_uniform_disk_polar(Vec2 p);

// Shirley-Chiu concentric map: squares to rings, lower distortion than the polar map
// (keeps stratification); the basis of the cosine hemisphere sampler.
Vec2 sample_uniform_disk_concentric(Vec2 u);
// The same point as (r, theta) with r >= 0: r is exact (|2u - 1| of one coordinate), so
// callers can form 1 - r^2 = (1 - r)(1 + r) without cancellation (cosine hemisphere).
struct DiskPolar {
  double r, theta;
};
DiskPolar sample_uniform_disk_concentric_polar(Vec2 u);
Vec2 invert_uniform_disk_concentric(Vec2 p);

// Rejection from the square [-1, 1]^2 (acceptance pi/4). Two uniforms per attempt.
std::optional<Vec2> sample_uniform_disk_rejection(SampleRng& rng, std::uint64_t max_attempts,
                                                  RejectionStats& stats);

// Uniform 2-D unit directions, density w.r.t. angle.
constexpr double direction_2d_pdf() {
  return kInv2Pi;
}
Vec2 sample_direction_2d(double u);  // (cos, sin) of 2 pi u
double invert_direction_2d(Vec2 d);

// The lecture's corrected rejection method: a point uniform in the disk has a uniform
// angle, so normalising it gives a uniform direction (normalising a point of the square
// would not: the corners over-weight the diagonals). The centre has no direction and is
// rejected too.
std::optional<Vec2> sample_direction_2d_rejection(SampleRng& rng, std::uint64_t max_attempts,
                                                  RejectionStats& stats);

}  // namespace tally
