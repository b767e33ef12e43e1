#include "common/integrate/genz.hpp"

#include <gtest/gtest.h>

#include <cmath>

namespace tally {
namespace {

// Test vectors of ../shared/references/genz.md (closed form vs Gauss-Legendre, 1e-13).
TEST(Genz, ClosedFormsMatchReferenceVectors) {
  const double d2[6] = {-0.694794487118, 4.84496959705, 0.0860640061201,
                        0.593597766948,  0.433114560345, 0.441237196312};
  const double d3[6] = {-0.528582115308, 2.28134485914, 0.0246020387228,
                        0.569581626436,  0.364905507329, 0.639007717711};
  for (int f = 0; f < 6; ++f) {
    GenzParams p2{static_cast<GenzFamily>(f), {1.3, 2.1}, {0.3, 0.6}};
    GenzParams p3{static_cast<GenzFamily>(f), {1.3, 2.1, 0.7}, {0.3, 0.6, 0.45}};
    EXPECT_NEAR(genz_exact(p2), d2[f], 1e-11 * std::max(1.0, std::fabs(d2[f]))) << genz_family_name(p2.family);
    EXPECT_NEAR(genz_exact(p3), d3[f], 1e-11 * std::max(1.0, std::fabs(d3[f]))) << genz_family_name(p3.family);
  }
}

TEST(Genz, PointValues) {
  const double x[2] = {0.25, 0.5};
  GenzParams osc{GenzFamily::oscillatory, {1.0, 2.0}, {0.0, 0.0}};
  EXPECT_DOUBLE_EQ(genz_value(osc, x), std::cos(0.25 + 1.0));
  GenzParams disc{GenzFamily::discontinuous, {1.0, 2.0}, {0.3, 0.9}};
  EXPECT_DOUBLE_EQ(genz_value(disc, x), std::exp(0.25 + 1.0));
  GenzParams disc2{GenzFamily::discontinuous, {1.0, 2.0}, {0.2, 0.9}};
  EXPECT_EQ(genz_value(disc2, x), 0.0);
}

TEST(Genz, RandomInstancesFollowCubaConvention) {
  const double h[6] = {6.0, 18.0, 2.2, 15.2, 16.1, 16.4};
  for (int f = 0; f < 6; ++f) {
    const GenzParams p = genz_random_instance(static_cast<GenzFamily>(f), 5, 77);
    double s = 0;
    for (double a : p.a) {
      EXPECT_GT(a, 0.0);
      s += a;
    }
    EXPECT_NEAR(s, h[f], 1e-12);
    for (double u : p.u) {
      EXPECT_GE(u, 0.0);
      EXPECT_LT(u, 1.0);
    }
  }
}

}  // namespace
}  // namespace tally
