#pragma once
// Uniform points in the unit d-ball, on the unit sphere S^{d-1} in R^d, and in the
// standard d-simplex, for d = 1 .. kMaxBallSimplexDim. Each sampler takes a fixed number
// of uniforms per d (see *_uniform_count), so it works with any point set (random,
// stratified, RQMC) and a sample's later dimensions never shift.
#include <cstdint>
#include <span>

#include "common/rng/counter_rng.hpp"

namespace tally {

inline constexpr std::uint32_t kMaxBallSimplexDim = 64;

// Gaussian directions by Box-Muller: one pair of uniforms per two coordinates.
constexpr std::uint32_t sphere_surface_uniform_count(std::uint32_t d) {
  return 2 * ((d + 1) / 2);
}
// Direction plus one uniform for the radius r = u^(1/d) (volume grows as r^d).
constexpr std::uint32_t ball_uniform_count(std::uint32_t d) {
  return sphere_surface_uniform_count(d) + 1;
}
// d + 1 exponential spacings, normalised (a flat Dirichlet), keep the first d.
constexpr std::uint32_t simplex_uniform_count(std::uint32_t d) {
  return d + 1;
}

// x.size() = d; u.size() = the matching *_uniform_count(d). Preconditions are checked
// and throw std::invalid_argument (they are set up once per job, not per sample).
void sample_uniform_sphere_surface(std::span<const double> u, std::span<double> x);
void sample_uniform_ball(std::span<const double> u, std::span<double> x);
void sample_uniform_simplex(std::span<const double> u, std::span<double> x);

// The same, drawing the uniforms from rng.next() (advances the rng's dimension counter
// by exactly the uniform count).
void sample_uniform_sphere_surface(SampleRng& rng, std::span<double> x);
void sample_uniform_ball(SampleRng& rng, std::span<double> x);
void sample_uniform_simplex(SampleRng& rng, std::span<double> x);

// Volume of the unit ball in R^d: pi^(d/2) / Gamma(d/2 + 1).
double unit_ball_volume(std::uint32_t d);
// Surface measure of the unit sphere S^{d-1} in R^d (d = 3: 4 pi): d * unit_ball_volume(d).
double sphere_surface_area(std::uint32_t d);
// Volume of {x_i >= 0, sum x_i <= 1} in R^d: 1 / d!.
double simplex_volume(std::uint32_t d);

inline double uniform_ball_pdf(std::uint32_t d) {
  return 1.0 / unit_ball_volume(d);
}
inline double uniform_sphere_surface_pdf(std::uint32_t d) {
  return 1.0 / sphere_surface_area(d);
}
inline double uniform_simplex_pdf(std::uint32_t d) {
  return 1.0 / simplex_volume(d);
}

}  // namespace tally
