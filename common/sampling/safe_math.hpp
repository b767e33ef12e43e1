#pragma once
// Small numeric helpers shared by the sampling routines. They exist so that every warp
// guards the same corner cases the same way (rounding that makes 1 - z^2 slightly
// negative, a uniform that rounds up to 1, angles that wrap to just below 0).
#include <algorithm>
#include <cmath>
#include <numbers>

namespace tally {

inline constexpr double kPi = std::numbers::pi;
inline constexpr double kInvPi = std::numbers::inv_pi;
inline constexpr double kInv2Pi = 0.5 * std::numbers::inv_pi;
inline constexpr double kInv4Pi = 0.25 * std::numbers::inv_pi;
inline constexpr double kPiOver2 = 0.5 * std::numbers::pi;
inline constexpr double kPiOver4 = 0.25 * std::numbers::pi;

// The largest double below 1: sampling inputs and inverse outputs live in [0, 1).
inline constexpr double kOneMinusEpsilon = 0x1.fffffffffffffp-1;

// sqrt that treats a slightly negative argument (from rounding) as 0 instead of NaN.
inline double safe_sqrt(double x) {
  return std::sqrt(std::max(0.0, x));
}

// Clamp a value that should be a uniform in [0, 1) back into that range: inverses
// computed in floating point can land on 1 or a hair below 0.
inline double clamp_unit(double u) {
  return std::clamp(u, 0.0, kOneMinusEpsilon);
}

// Angle atan2(y, x) in (-pi, pi] mapped to a uniform in [0, 1) (angle / 2 pi, wrapped).
inline double angle_to_unit(double y, double x) {
  double u = std::atan2(y, x) * kInv2Pi;
  if (u < 0) u += 1.0;
  return clamp_unit(u);
}

}  // namespace tally
