#pragma once
// The six Genz families as a GSL user would write them: one scalar C function per
// point (no allocation), with parameters behind a void pointer. Same formulas as
// common/integrate/genz.cpp; the study checks both against genz_exact.
#include <cmath>
#include <cstddef>
#include <numbers>

namespace tally::peers {

struct GenzScalar {
  int family = 0;  // 0 oscillatory .. 5 discontinuous (GenzFamily order)
  size_t d = 0;
  const double* a = nullptr;
  const double* u = nullptr;
  unsigned long long* evaluations = nullptr;  // counts every call
};

inline double genz_scalar(const double* x, size_t d, const GenzScalar& g) {
  ++*g.evaluations;
  const double* a = g.a;
  const double* u = g.u;
  switch (g.family) {
    case 0: {
      double s = 2 * std::numbers::pi * u[0];
      for (size_t i = 0; i < d; ++i) s += a[i] * x[i];
      return std::cos(s);
    }
    case 1: {
      double p = 1.0;
      for (size_t i = 0; i < d; ++i) p *= 1.0 / (1.0 / (a[i] * a[i]) + (x[i] - u[i]) * (x[i] - u[i]));
      return p;
    }
    case 2: {
      double s = 1.0;
      for (size_t i = 0; i < d; ++i) s += a[i] * x[i];
      return std::pow(s, -static_cast<double>(d + 1));
    }
    case 3: {
      double s = 0.0;
      for (size_t i = 0; i < d; ++i) s += a[i] * a[i] * (x[i] - u[i]) * (x[i] - u[i]);
      return std::exp(-s);
    }
    case 4: {
      double s = 0.0;
      for (size_t i = 0; i < d; ++i) s += a[i] * std::fabs(x[i] - u[i]);
      return std::exp(-s);
    }
    default: {
      if (x[0] > u[0] || (d > 1 && x[1] > u[1])) return 0.0;
      double s = 0.0;
      for (size_t i = 0; i < d; ++i) s += a[i] * x[i];
      return std::exp(s);
    }
  }
}

// gsl_monte_function's signature.
inline double genz_scalar_gsl(double* x, size_t d, void* params) {
  return genz_scalar(x, d, *static_cast<const GenzScalar*>(params));
}

}  // namespace tally::peers
