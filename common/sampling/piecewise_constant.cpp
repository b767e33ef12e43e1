#include "common/sampling/piecewise_constant.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "common/sampling/safe_math.hpp"

namespace tally {
namespace {

std::vector<double> checked_values(std::span<const double> values, double min, double max) {
  if (!(std::isfinite(min) && std::isfinite(max) && min < max)) {
    throw std::invalid_argument("PiecewiseConstant1D: need finite min < max, got [" +
                                std::to_string(min) + ", " + std::to_string(max) + "]");
  }
  validate_weights(values, "PiecewiseConstant1D");
  return {values.begin(), values.end()};
}

// Row integrals of a 2-D table. Rows that are all zero get weight 0 in the marginal.
std::vector<double> row_integrals(std::span<const double> values, std::size_t nu, std::size_t nv,
                                  double du) {
  std::vector<double> rows(nv, 0.0);
  for (std::size_t v = 0; v < nv; ++v) {
    for (std::size_t u = 0; u < nu; ++u) rows[v] += values[v * nu + u];
    rows[v] *= du;
  }
  return rows;
}

std::span<const double> checked_table(std::span<const double> values, std::size_t nu,
                                      std::size_t nv, const Box2& domain) {
  if (!(std::isfinite(domain.lo.x) && std::isfinite(domain.hi.x) && domain.lo.x < domain.hi.x)) {
    throw std::invalid_argument("PiecewiseConstant2D: need finite domain.lo.x < domain.hi.x");
  }
  if (nu == 0 || nv == 0 || values.size() != nu * nv) {
    throw std::invalid_argument("PiecewiseConstant2D: expected nu * nv = " + std::to_string(nu) +
                                " * " + std::to_string(nv) + " values, got " +
                                std::to_string(values.size()));
  }
  validate_weights(values, "PiecewiseConstant2D");
  return values;
}

}  // namespace

PiecewiseConstant1D::PiecewiseConstant1D(std::span<const double> values, double min, double max)
    : values_(checked_values(values, min, max)), cdf_(values) {
  const std::size_t n = values_.size();
  edges_.resize(n + 1);
  for (std::size_t i = 0; i <= n; ++i) {
    edges_[i] = min + (max - min) * (static_cast<double>(i) / static_cast<double>(n));
  }
  edges_.back() = max;
  double sum = 0;
  for (const double v : values_) sum += v;
  integral_ = sum * (max - min) / static_cast<double>(n);
  if (!std::isfinite(integral_) || !(integral_ > 0)) {
    throw std::invalid_argument("PiecewiseConstant1D: integral is not a positive finite number");
  }
}

std::size_t PiecewiseConstant1D::cell_of(double x) const {
  const std::size_t n = values_.size();
  // Guess from the uniform spacing, then settle against the stored edges, so that lookup
  // agrees bit for bit with the cell that sample() placed x in.
  const double t = (x - edges_.front()) / (edges_.back() - edges_.front()) * static_cast<double>(n);
  std::size_t c = t <= 0 ? 0 : std::min(static_cast<std::size_t>(t), n - 1);
  while (c > 0 && x < edges_[c]) --c;
  while (c + 1 < n && x >= edges_[c + 1]) ++c;
  return c;
}

PiecewiseConstant1D::Sample PiecewiseConstant1D::sample(double u) const {
  double du = 0;
  const std::size_t c = cdf_.sample_remapped(u, &du);
  const double lo = edges_[c], hi = edges_[c + 1];
  // lo + du * (hi - lo) can round up to hi, which belongs to the next (maybe zero) cell.
  const double x = std::min(lo + du * (hi - lo), std::nextafter(hi, lo));
  return {x, values_[c] / integral_, c};
}

double PiecewiseConstant1D::pdf(double x) const {
  if (!(x >= edges_.front() && x <= edges_.back())) return 0.0;
  return values_[cell_of(x)] / integral_;
}

double PiecewiseConstant1D::invert(double x) const {
  x = std::clamp(x, edges_.front(), edges_.back());
  const std::size_t c = cell_of(x);
  const double t = std::clamp((x - edges_[c]) / (edges_[c + 1] - edges_[c]), 0.0, 1.0);
  return clamp_unit(cdf_.cdf(c) + t * (cdf_.cdf(c + 1) - cdf_.cdf(c)));
}

PiecewiseConstant2D::PiecewiseConstant2D(std::span<const double> values, std::size_t nu,
                                         std::size_t nv, Box2 domain)
    : nu_(nu),
      nv_(nv),
      values_(checked_table(values, nu, nv, domain).begin(), values.end()),
      marginal_(
          row_integrals(values, nu, nv, (domain.hi.x - domain.lo.x) / static_cast<double>(nu)),
          domain.lo.y, domain.hi.y) {
  conditional_.reserve(nv);
  const std::vector<double> ones(nu, 1.0);
  for (std::size_t v = 0; v < nv; ++v) {
    const std::span<const double> row = values.subspan(v * nu, nu);
    const bool empty_row = std::all_of(row.begin(), row.end(), [](double f) { return f == 0; });
    // An all-zero row has zero marginal probability and is never sampled; a uniform
    // stand-in keeps invert() defined there.
    conditional_.emplace_back(empty_row ? std::span<const double>(ones) : row, domain.lo.x,
                              domain.hi.x);
  }
}

PiecewiseConstant2D::Sample PiecewiseConstant2D::sample(Vec2 u) const {
  const PiecewiseConstant1D::Sample sv = marginal_.sample(u.y);
  const PiecewiseConstant1D::Sample su = conditional_[sv.cell].sample(u.x);
  // p(u, v) = p(v) * p(u | v) = f(u, v) / integral.
  return {{su.x, sv.x}, values_[sv.cell * nu_ + su.cell] / integral()};
}

double PiecewiseConstant2D::pdf(Vec2 p) const {
  if (marginal_.pdf(p.y) == 0) return 0.0;  // outside the box in v, or an empty row
  const std::size_t v = marginal_.cell_of(p.y);
  const PiecewiseConstant1D& row = conditional_[v];
  if (!(p.x >= row.min() && p.x <= row.max())) return 0.0;
  return values_[v * nu_ + row.cell_of(p.x)] / integral();
}

std::array<std::size_t, 2> PiecewiseConstant2D::cell_of(Vec2 p) const {
  const std::size_t v = marginal_.cell_of(std::clamp(p.y, marginal_.min(), marginal_.max()));
  const PiecewiseConstant1D& row = conditional_[v];
  return {row.cell_of(std::clamp(p.x, row.min(), row.max())), v};
}

Vec2 PiecewiseConstant2D::invert(Vec2 p) const {
  const double uv = marginal_.invert(p.y);
  const std::size_t v = marginal_.cell_of(std::clamp(p.y, marginal_.min(), marginal_.max()));
  return {conditional_[v].invert(p.x), uv};
}

}  // namespace tally
