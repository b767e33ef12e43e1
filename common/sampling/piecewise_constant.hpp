#pragma once
// Piecewise-constant densities by inverse CDF (pbrt-v4 PiecewiseConstant1D/2D): sample a
// tabulated function (an environment map, a user histogram) proportionally to its value.
// 2-D uses a marginal over rows and one conditional per row. Both are invertible, which
// keeps them usable with stratified and QMC points and in round-trip tests.
#include <array>
#include <cstddef>
#include <span>
#include <vector>

#include "common/math/vec3.hpp"
#include "common/sampling/discrete_cdf.hpp"

namespace tally {

class PiecewiseConstant1D {
 public:
  struct Sample {
    double x;          // in [min, max)
    double pdf;        // density w.r.t. x, > 0
    std::size_t cell;  // index of the cell x lies in
  };

  // values: one per equal-width cell over [min, max); finite and >= 0, not all zero;
  // min < max, both finite. Violations throw std::invalid_argument.
  explicit PiecewiseConstant1D(std::span<const double> values, double min = 0.0, double max = 1.0);

  Sample sample(double u) const;
  double pdf(double x) const;     // 0 outside [min, max] and in zero-valued cells
  double invert(double x) const;  // the u with sample(u).x == x (x clamped to the domain)
  double integral() const { return integral_; }  // of the function over [min, max]

  std::size_t size() const { return values_.size(); }
  double min() const { return edges_.front(); }
  double max() const { return edges_.back(); }
  std::size_t cell_of(double x) const;

 private:
  std::vector<double> values_;
  std::vector<double> edges_;  // size() + 1 cell boundaries; edges_.back() == max exactly
  DiscreteCdf cdf_;
  double integral_;
};

struct Box2 {
  Vec2 lo{0.0, 0.0};
  Vec2 hi{1.0, 1.0};
};

class PiecewiseConstant2D {
 public:
  struct Sample {
    Vec2 point;  // in the box
    double pdf;  // density w.r.t. area in the box, > 0
  };

  // values: nu * nv entries, row-major with rows along v: values[iv * nu + iu] is the
  // cell [iu, iu + 1) x [iv, iv + 1) of the grid over `domain`. Same validation as 1-D.
  PiecewiseConstant2D(std::span<const double> values, std::size_t nu, std::size_t nv,
                      Box2 domain = {});

  // u.y picks the row from the marginal, u.x the point within the row (conditional).
  Sample sample(Vec2 u) const;
  double pdf(Vec2 p) const;
  Vec2 invert(Vec2 p) const;
  double integral() const { return marginal_.integral(); }
  // The cell {iu, iv} of the grid that pdf() reads for p (p clamped into the box): lets a
  // caller look up its own per-cell data exactly where the density is taken.
  std::array<std::size_t, 2> cell_of(Vec2 p) const;

 private:
  std::size_t nu_, nv_;
  std::vector<double> values_;
  std::vector<PiecewiseConstant1D> conditional_;  // one per row (v)
  PiecewiseConstant1D marginal_;                  // over v; row integrals
};

}  // namespace tally
