#include "common/sampling/ball_simplex.hpp"

#include <array>
#include <cmath>
#include <stdexcept>
#include <string>

#include "common/sampling/safe_math.hpp"

namespace tally {
namespace {

void check(std::size_t u_size, std::size_t x_size, std::uint32_t need, const char* what) {
  if (x_size == 0 || x_size > kMaxBallSimplexDim) {
    throw std::invalid_argument(std::string(what) + ": dimension " + std::to_string(x_size) +
                                " outside [1, " + std::to_string(kMaxBallSimplexDim) + "]");
  }
  if (u_size != need) {
    throw std::invalid_argument(std::string(what) + ": needs " + std::to_string(need) +
                                " uniforms, got " + std::to_string(u_size));
  }
}

// Independent standard normals into x (Box-Muller); returns |x|^2.
double gaussians(std::span<const double> u, std::span<double> x) {
  double norm2 = 0;
  for (std::size_t i = 0; i < x.size(); i += 2) {
    // 1 - u is in (0, 1], so the log is finite.
    const double radius = std::sqrt(-2.0 * std::log1p(-u[i]));
    const double angle = 2.0 * kPi * u[i + 1];
    x[i] = radius * std::cos(angle);
    if (i + 1 < x.size()) x[i + 1] = radius * std::sin(angle);
  }
  for (const double xi : x) norm2 += xi * xi;
  return norm2;
}

// Normalise Gaussians to a unit vector. |x| = 0 needs every radial uniform to be exactly
// 0 (probability 2^-53 per pair); return the first axis then instead of 0/0.
void to_unit(std::span<double> x, double norm2) {
  if (!(norm2 > 0)) {
    for (double& xi : x) xi = 0;
    x[0] = 1;
    return;
  }
  const double inv = 1.0 / std::sqrt(norm2);
  for (double& xi : x) xi *= inv;
}

template <class Fn>
void with_rng(SampleRng& rng, std::uint32_t count, Fn&& fn) {
  std::array<double, 2 * kMaxBallSimplexDim + 2> u{};
  if (count > u.size()) throw std::invalid_argument("ball/simplex sampler: dimension too large");
  for (std::uint32_t i = 0; i < count; ++i) u[i] = rng.next();
  fn(std::span<const double>(u.data(), count));
}

}  // namespace

void sample_uniform_sphere_surface(std::span<const double> u, std::span<double> x) {
  const auto d = static_cast<std::uint32_t>(x.size());
  check(u.size(), x.size(), sphere_surface_uniform_count(d), "sample_uniform_sphere_surface");
  to_unit(x, gaussians(u, x));
}

void sample_uniform_ball(std::span<const double> u, std::span<double> x) {
  const auto d = static_cast<std::uint32_t>(x.size());
  check(u.size(), x.size(), ball_uniform_count(d), "sample_uniform_ball");
  to_unit(x, gaussians(u.first(u.size() - 1), x));
  const double r = std::pow(u.back(), 1.0 / static_cast<double>(d));
  for (double& xi : x) xi *= r;
}

void sample_uniform_simplex(std::span<const double> u, std::span<double> x) {
  const auto d = static_cast<std::uint32_t>(x.size());
  check(u.size(), x.size(), simplex_uniform_count(d), "sample_uniform_simplex");
  // E_i = -log(1 - u_i) are Exp(1); E / sum(E) over d + 1 of them is uniform on the
  // d-simplex in R^{d+1}; dropping the last coordinate gives the solid simplex in R^d.
  double total = 0;
  for (std::uint32_t i = 0; i <= d; ++i) {
    const double e = -std::log1p(-u[i]);
    if (i < d) x[i] = e;
    total += e;
  }
  if (!(total > 0)) {  // every u_i exactly 0: return the origin, a point of the simplex
    for (double& xi : x) xi = 0;
    return;
  }
  for (double& xi : x) xi /= total;
}

void sample_uniform_sphere_surface(SampleRng& rng, std::span<double> x) {
  with_rng(rng, sphere_surface_uniform_count(static_cast<std::uint32_t>(x.size())),
           [&](std::span<const double> u) { sample_uniform_sphere_surface(u, x); });
}
void sample_uniform_ball(SampleRng& rng, std::span<double> x) {
  with_rng(rng, ball_uniform_count(static_cast<std::uint32_t>(x.size())),
           [&](std::span<const double> u) { sample_uniform_ball(u, x); });
}
void sample_uniform_simplex(SampleRng& rng, std::span<double> x) {
  with_rng(rng, simplex_uniform_count(static_cast<std::uint32_t>(x.size())),
           [&](std::span<const double> u) { sample_uniform_simplex(u, x); });
}

double unit_ball_volume(std::uint32_t d) {
  // V_0 = 1, V_1 = 2, V_d = (2 pi / d) V_{d-2}: no Gamma function, no overflow.
  double v = (d % 2 == 0) ? 1.0 : 2.0;
  for (std::uint32_t k = (d % 2 == 0) ? 2 : 3; k <= d; k += 2)
    v *= 2.0 * kPi / static_cast<double>(k);
  return v;
}

double sphere_surface_area(std::uint32_t d) {
  return static_cast<double>(d) * unit_ball_volume(d);
}

double simplex_volume(std::uint32_t d) {
  double v = 1.0;
  for (std::uint32_t k = 2; k <= d; ++k) v /= static_cast<double>(k);
  return v;
}

}  // namespace tally
