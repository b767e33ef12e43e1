// PiecewiseConstant1D/2D: chi-square against a reference density built independently
// from the table, zero cells never sampled, pdf and inverse round trips, validation.
#include "common/sampling/piecewise_constant.hpp"

#include <cmath>
#include <limits>
#include <stdexcept>
#include <vector>

#include <gtest/gtest.h>

#include "chi_square_support.hpp"
#include "common/rng/counter_rng.hpp"

namespace tally {
namespace {

using test::passes_chi_square;

constexpr std::uint64_t kSeed = 0x91ece'415e;

Vec2 u2(std::uint64_t stream, std::uint64_t index) {
  const SampleRng r(stream_key(kSeed, stream), index);
  return {r.uniform(0), r.uniform(1)};
}

// 37 cells over [-2, 3] with zero runs at both ends and inside, and a spike.
std::vector<double> values_1d() {
  std::vector<double> v(37);
  for (std::size_t i = 0; i < v.size(); ++i) v[i] = 1.0 + std::sin(0.7 * static_cast<double>(i));
  v[0] = v[1] = v[15] = v[16] = v[17] = v[36] = 0.0;
  v[25] = 9.0;
  return v;
}

// Reference density, computed here rather than trusting the class under test.
double reference_pdf_1d(const std::vector<double>& v, double lo, double hi, double x) {
  if (x < lo || x > hi) return 0;
  const double width = (hi - lo) / static_cast<double>(v.size());
  double total = 0;
  for (const double f : v) total += f * width;
  const auto cell = std::min(static_cast<std::size_t>((x - lo) / width), v.size() - 1);
  return v[cell] / total;
}

TEST(PiecewiseConstant1D, MatchesFunction) {
  const std::vector<double> v = values_1d();
  const PiecewiseConstant1D dist(v, -2.0, 3.0);
  // 101 histogram cells are not aligned with the 37 function cells: the harness's
  // sub-cell integration handles the steps.
  EXPECT_TRUE(passes_chi_square(test::chi_square_1d(
      -2.0, 3.0, 101,
      [&](std::uint64_t i) -> std::optional<double> {
        const PiecewiseConstant1D::Sample s = dist.sample(u2(1, i).x);
        if (s.pdf != dist.pdf(s.x) || s.cell != dist.cell_of(s.x)) return std::nullopt;
        return s.x;
      },
      [&](double x) { return reference_pdf_1d(v, -2.0, 3.0, x); },
      {.samples = 1'000'000, .subdivisions = 64, .min_expected = 5.0})));  // 4096 points per cell
}

TEST(PiecewiseConstant1D, PdfIntegralAndRoundTrip) {
  const std::vector<double> v = values_1d();
  const PiecewiseConstant1D dist(v, -2.0, 3.0);
  double sum = 0;
  for (const double f : v) sum += f;
  EXPECT_NEAR(dist.integral(), sum * 5.0 / 37.0, 1e-12);
  EXPECT_EQ(dist.pdf(-2.5), 0.0);
  EXPECT_EQ(dist.pdf(3.5), 0.0);
  for (const double u : test::unit_test_grid(10'001)) {
    const PiecewiseConstant1D::Sample s = dist.sample(u);
    ASSERT_TRUE(s.x >= -2.0 && s.x < 3.0) << u;
    ASSERT_GT(v[s.cell], 0.0) << u;  // zero-valued cells are never sampled
    ASSERT_GT(s.pdf, 0.0) << u;
    ASSERT_TRUE(std::isfinite(s.pdf)) << u;
    // The reported cell holds x and has the reference density (a reference that recomputes
    // the cell from x by floor() can disagree by an ulp on an exact cell edge).
    ASSERT_EQ(s.pdf, dist.pdf(s.x)) << u;
    ASSERT_NEAR(s.pdf, v[s.cell] / (sum * 5.0 / 37.0), 1e-12) << u;
    ASSERT_NEAR(s.x, -2.0 + (static_cast<double>(s.cell) + 0.5) * 5.0 / 37.0,
                0.5 * 5.0 / 37.0 + 1e-12)
        << u;
    const double back = dist.invert(s.x);
    ASSERT_TRUE(back >= 0 && back < 1) << u;
    EXPECT_NEAR(back, u, 1e-6) << u;
  }
}

TEST(PiecewiseConstant1D, UpperEdgeStaysInItsCell) {
  // A sample near the top of a cell must not round into the next (zero) cell.
  const std::vector<double> v = {0.0, 1.0, 0.0};
  const PiecewiseConstant1D dist(v, 0.1, 0.7);
  const PiecewiseConstant1D::Sample s = dist.sample(std::nextafter(1.0, 0.0));
  EXPECT_EQ(s.cell, 1u);
  EXPECT_GT(dist.pdf(s.x), 0.0);
  EXPECT_EQ(dist.cell_of(s.x), 1u);
}

TEST(PiecewiseConstant1D, RejectsInvalidInput) {
  const std::vector<double> zeros = {0.0, 0.0};
  const std::vector<double> neg = {1.0, -1.0};
  const std::vector<double> ok = {1.0};
  EXPECT_THROW(PiecewiseConstant1D(zeros, 0, 1), std::invalid_argument);
  EXPECT_THROW(PiecewiseConstant1D(neg, 0, 1), std::invalid_argument);
  EXPECT_THROW(PiecewiseConstant1D(ok, 1, 1), std::invalid_argument);
  EXPECT_THROW(PiecewiseConstant1D(ok, 0, std::numeric_limits<double>::infinity()),
               std::invalid_argument);
  EXPECT_THROW(PiecewiseConstant1D(std::vector<double>{}, 0, 1), std::invalid_argument);
}

// 7 x 5 table over [1, 3] x [-1, 0.5], with an all-zero row and scattered zero cells.
constexpr std::size_t kNu = 7, kNv = 5;
const Box2 kBox{{1.0, -1.0}, {3.0, 0.5}};
std::vector<double> values_2d() {
  std::vector<double> v(kNu * kNv);
  for (std::size_t iv = 0; iv < kNv; ++iv) {
    for (std::size_t iu = 0; iu < kNu; ++iu) {
      v[iv * kNu + iu] = 0.5 + static_cast<double>((3 * iu + 5 * iv) % 7);
    }
  }
  for (std::size_t iu = 0; iu < kNu; ++iu) v[2 * kNu + iu] = 0.0;  // empty row
  v[0] = v[4 * kNu + 6] = v[1 * kNu + 3] = 0.0;
  v[3 * kNu + 2] = 20.0;
  return v;
}

double reference_pdf_2d(const std::vector<double>& v, Vec2 p) {
  if (p.x < kBox.lo.x || p.x > kBox.hi.x || p.y < kBox.lo.y || p.y > kBox.hi.y) return 0;
  const double wu = (kBox.hi.x - kBox.lo.x) / kNu, wv = (kBox.hi.y - kBox.lo.y) / kNv;
  double total = 0;
  for (const double f : v) total += f * wu * wv;
  const auto iu = std::min(static_cast<std::size_t>((p.x - kBox.lo.x) / wu), kNu - 1);
  const auto iv = std::min(static_cast<std::size_t>((p.y - kBox.lo.y) / wv), kNv - 1);
  return v[iv * kNu + iu] / total;
}

TEST(PiecewiseConstant2D, MatchesFunction) {
  const std::vector<double> v = values_2d();
  const PiecewiseConstant2D dist(v, kNu, kNv, kBox);
  EXPECT_TRUE(passes_chi_square(test::chi_square_2d(
      {kBox.lo.x, kBox.hi.x, kBox.lo.y, kBox.hi.y, 80, 60},
      [&](std::uint64_t i) -> std::optional<Vec2> {
        const PiecewiseConstant2D::Sample s = dist.sample(u2(2, i));
        if (s.pdf != dist.pdf(s.point)) return std::nullopt;
        return s.point;
      },
      [&](Vec2 p) { return reference_pdf_2d(v, p); },
      {.samples = 1'000'000, .subdivisions = 32, .min_expected = 5.0})));
}

TEST(PiecewiseConstant2D, PdfAndRoundTrip) {
  const std::vector<double> v = values_2d();
  const PiecewiseConstant2D dist(v, kNu, kNv, kBox);
  EXPECT_EQ(dist.pdf({0.5, 0.0}), 0.0);
  EXPECT_EQ(dist.pdf({2.0, 1.0}), 0.0);
  EXPECT_EQ(dist.pdf({2.0, -0.3}), 0.0);  // the empty row
  for (const double a : test::unit_test_grid(101)) {
    for (const double b : test::unit_test_grid(101)) {
      const PiecewiseConstant2D::Sample s = dist.sample({a, b});
      ASSERT_TRUE(s.point.x >= kBox.lo.x && s.point.x < kBox.hi.x && s.point.y >= kBox.lo.y &&
                  s.point.y < kBox.hi.y)
          << a << " " << b;
      ASSERT_GT(s.pdf, 0.0) << a << " " << b;
      ASSERT_EQ(s.pdf, dist.pdf(s.point)) << a << " " << b;
      // The floor()-based reference can pick the neighbour cell on an exact cell edge, so
      // one of the points 1e-12 around the sample must agree.
      bool matches = false;
      for (const double dx : {-1e-12, 0.0, 1e-12}) {
        for (const double dy : {-1e-12, 0.0, 1e-12}) {
          const Vec2 q{s.point.x + dx, s.point.y + dy};
          matches = matches || std::abs(s.pdf - reference_pdf_2d(v, q)) <= 1e-12;
        }
      }
      ASSERT_TRUE(matches) << a << " " << b << " pdf " << s.pdf;
      const Vec2 back = dist.invert(s.point);
      ASSERT_TRUE(back.x >= 0 && back.x < 1 && back.y >= 0 && back.y < 1) << a << " " << b;
      EXPECT_NEAR(back.x, a, 1e-6) << a << " " << b;
      EXPECT_NEAR(back.y, b, 1e-6) << a << " " << b;
    }
  }
}

TEST(PiecewiseConstant2D, CellOfIsTheCellThePdfReads) {
  // cell_of(p) names the table entry pdf(p) is taken from (the environment map looks its
  // texels up with it), for sampled points and, clamped, for points outside the box.
  const std::vector<double> v = values_2d();
  const PiecewiseConstant2D dist(v, kNu, kNv, kBox);
  for (std::uint64_t i = 0; i < 20000; ++i) {
    const PiecewiseConstant2D::Sample s = dist.sample(u2(9, i));
    const auto [iu, iv] = dist.cell_of(s.point);
    ASSERT_LT(iu, kNu);
    ASSERT_LT(iv, kNv);
    EXPECT_EQ(s.pdf, v[iv * kNu + iu] / dist.integral()) << i;
  }
  EXPECT_EQ(dist.cell_of({kBox.hi.x, kBox.hi.y}), (std::array<std::size_t, 2>{kNu - 1, kNv - 1}));
  EXPECT_EQ(dist.cell_of({-5.0, -5.0}), (std::array<std::size_t, 2>{0, 0}));
  EXPECT_EQ(dist.cell_of({1.0 + 2.0 / 7 * 3.5, -1.0 + 1.5 / 5 * 4.5}), (std::array<std::size_t, 2>{3, 4}));
}

TEST(PiecewiseConstant2D, RejectsInvalidInput) {
  const std::vector<double> zeros(6, 0.0);
  const std::vector<double> ones(6, 1.0);
  EXPECT_THROW(PiecewiseConstant2D(zeros, 3, 2), std::invalid_argument);
  EXPECT_THROW(PiecewiseConstant2D(ones, 4, 2), std::invalid_argument);
  EXPECT_THROW(PiecewiseConstant2D(ones, 3, 2, Box2{{1, 0}, {0, 1}}), std::invalid_argument);
  EXPECT_THROW(PiecewiseConstant2D(ones, 3, 2, Box2{{0, 1}, {1, 1}}), std::invalid_argument);
}

}  // namespace
}  // namespace tally
