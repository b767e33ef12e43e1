#include "chi_square_support.hpp"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <sstream>

#include <boost/math/distributions/chi_squared.hpp>

namespace tally::test {
namespace {

std::atomic<int> g_chi_square_tests_run{0};

// Fails the run if more chi-square tests ran than kChiSquareTestCount declares: the
// Sidak correction would then be too loose.
class ChiSquareCountCheck : public ::testing::Environment {
 public:
  void TearDown() override {
    const int run = g_chi_square_tests_run.load();
    if (::testing::GTEST_FLAG(filter) == "*") {
      EXPECT_EQ(run, kChiSquareTestCount) << "set kChiSquareTestCount in chi_square_support.hpp";
    } else {
      EXPECT_LE(run, kChiSquareTestCount) << "raise kChiSquareTestCount in chi_square_support.hpp";
    }
  }
};
[[maybe_unused]] ::testing::Environment* const g_count_check =
    ::testing::AddGlobalTestEnvironment(new ChiSquareCountCheck);

}  // namespace

double chi_square_test_alpha() {
  return -std::expm1(std::log1p(-kChiSquareSuiteAlpha) / kChiSquareTestCount);
}

std::string ChiSquareResult::summary() const {
  std::ostringstream s;
  s << "chi2 = " << statistic << ", dof = " << dof << ", p = " << p_value
    << " (alpha' = " << chi_square_test_alpha() << "), samples = " << samples
    << ", failed = " << failed << ", outside = " << outside << ", at pdf 0 = " << zero_pdf
    << ", in zero cells = " << zero_cell_hits << ", pdf integral = " << pdf_integral;
  return s.str();
}

void chi_square_from_counts(std::span<const double> expected,
                            std::span<const std::uint64_t> observed, double min_expected,
                            ChiSquareResult& result) {
  struct Cell {
    double expected;
    std::uint64_t observed;
  };
  std::vector<Cell> cells;
  cells.reserve(expected.size());
  for (std::size_t i = 0; i < expected.size(); ++i) {
    if (expected[i] > 0) {
      cells.push_back({expected[i], observed[i]});
    } else {
      result.zero_cell_hits += observed[i];
    }
  }
  // Mitsuba's pooling: smallest expected counts first, merged until the pool reaches
  // min_expected; the pool then counts as one cell.
  std::sort(cells.begin(), cells.end(),
            [](const Cell& a, const Cell& b) { return a.expected < b.expected; });
  double stat = 0, pool_expected = 0, pool_observed = 0;
  int bins = 0;
  for (const Cell& c : cells) {
    if (c.expected < min_expected || (pool_expected > 0 && pool_expected < min_expected)) {
      pool_expected += c.expected;
      pool_observed += static_cast<double>(c.observed);
      continue;
    }
    const double d = static_cast<double>(c.observed) - c.expected;
    stat += d * d / c.expected;
    ++bins;
  }
  if (pool_expected > 0) {
    const double d = pool_observed - pool_expected;
    stat += d * d / pool_expected;
    ++bins;
  }
  result.statistic = stat;
  result.dof = bins - 1;
  if (result.dof < 1) {
    result.p_value = 0;
    return;
  }
  const boost::math::chi_squared_distribution<double> dist(result.dof);
  result.p_value = boost::math::cdf(boost::math::complement(dist, stat));
}

namespace {

ChiSquareResult chi_square_grid(const Histogram2D& h, const Sampler2& sample, const Pdf2& pdf,
                                const ChiSquareOptions& options, int mx, int my) {
  ChiSquareResult r;
  r.samples = options.samples;
  const std::size_t ncells = static_cast<std::size_t>(h.nx) * static_cast<std::size_t>(h.ny);
  std::vector<std::uint64_t> counts(ncells, 0);
  const double wx = (h.x1 - h.x0) / h.nx, wy = (h.y1 - h.y0) / h.ny;
  for (std::uint64_t i = 0; i < options.samples; ++i) {
    const std::optional<Vec2> p = sample(i);
    if (!p) {
      ++r.failed;
      continue;
    }
    if (!(p->x >= h.x0 && p->x <= h.x1 && p->y >= h.y0 && p->y <= h.y1)) {
      ++r.outside;
      continue;
    }
    const double density = pdf(*p);
    if (!(density > 0) || !std::isfinite(density)) ++r.zero_pdf;
    const int ix = std::min(static_cast<int>((p->x - h.x0) / wx), h.nx - 1);
    const int iy = std::min(static_cast<int>((p->y - h.y0) / wy), h.ny - 1);
    ++counts[static_cast<std::size_t>(iy) * static_cast<std::size_t>(h.nx) +
             static_cast<std::size_t>(ix)];
  }
  // Expected counts: midpoint rule on an mx x my grid inside each cell. Cells cut by the
  // edge of the support (some points with pdf 0, some not) are integrated again on a grid
  // kRefine times finer per axis, so the edge costs well under a count per cell and the
  // normalisation check stays meaningful.
  constexpr int kRefine = 8;
  const auto integrate_cell = [&](int ix, int iy, int nx_sub, int ny_sub, bool* mixed) {
    double sum = 0;
    bool any_zero = false, any_positive = false;
    for (int sy = 0; sy < ny_sub; ++sy) {
      for (int sx = 0; sx < nx_sub; ++sx) {
        const Vec2 q{h.x0 + (ix + (sx + 0.5) / nx_sub) * wx,
                     h.y0 + (iy + (sy + 0.5) / ny_sub) * wy};
        const double v = pdf(q);
        sum += v;
        any_zero = any_zero || v == 0;
        any_positive = any_positive || v > 0;
      }
    }
    if (mixed != nullptr) *mixed = any_zero && any_positive;
    return sum * wx * wy / (static_cast<double>(nx_sub) * ny_sub);
  };
  const double drawn = static_cast<double>(options.samples - r.failed);
  std::vector<double> expected(ncells, 0.0);
  for (int iy = 0; iy < h.ny; ++iy) {
    for (int ix = 0; ix < h.nx; ++ix) {
      bool mixed = false;
      double integral = integrate_cell(ix, iy, mx, my, &mixed);
      if (mixed)
        integral = integrate_cell(ix, iy, mx * kRefine, my == 1 ? 1 : my * kRefine, nullptr);
      r.pdf_integral += integral;
      expected[static_cast<std::size_t>(iy) * static_cast<std::size_t>(h.nx) +
               static_cast<std::size_t>(ix)] = integral * drawn;
    }
  }
  chi_square_from_counts(expected, counts, options.min_expected, r);
  return r;
}

}  // namespace

ChiSquareResult chi_square_2d(const Histogram2D& h, const Sampler2& sample, const Pdf2& pdf,
                              const ChiSquareOptions& options) {
  return chi_square_grid(h, sample, pdf, options, options.subdivisions, options.subdivisions);
}

ChiSquareResult chi_square_1d(double x0, double x1, int cells, const Sampler1& sample,
                              const Pdf1& pdf, const ChiSquareOptions& options) {
  // A 1-D histogram is a 2-D one with a single row of unit height.
  const int m = std::max(options.subdivisions, 1);
  return chi_square_grid(
      {x0, x1, 0.0, 1.0, cells, 1},
      [&](std::uint64_t i) -> std::optional<Vec2> {
        const std::optional<double> x = sample(i);
        if (!x) return std::nullopt;
        return Vec2{*x, 0.5};
      },
      [&](Vec2 p) { return pdf(p.x); }, options, m* m, 1);
}

ChiSquareResult chi_square_discrete(std::span<const double> probabilities,
                                    const SamplerDiscrete& sample,
                                    const ChiSquareOptions& options) {
  ChiSquareResult r;
  r.samples = options.samples;
  std::vector<std::uint64_t> counts(probabilities.size(), 0);
  for (std::uint64_t i = 0; i < options.samples; ++i) {
    const std::size_t k = sample(i);
    if (k >= counts.size()) {
      ++r.outside;
      continue;
    }
    if (!(probabilities[k] > 0)) ++r.zero_pdf;
    ++counts[k];
  }
  std::vector<double> expected(probabilities.size());
  for (std::size_t k = 0; k < probabilities.size(); ++k) {
    r.pdf_integral += probabilities[k];
    expected[k] = probabilities[k] * static_cast<double>(options.samples);
  }
  chi_square_from_counts(expected, counts, options.min_expected, r);
  return r;
}

::testing::AssertionResult passes_chi_square(const ChiSquareResult& r) {
  ++g_chi_square_tests_run;
  const bool ok = r.failed == 0 && r.outside == 0 && r.zero_pdf == 0 && r.zero_cell_hits == 0 &&
                  r.pdf_integral <= 1.1 && std::abs(r.pdf_integral - 1.0) <= 1e-3 && r.dof >= 1 &&
                  r.p_value >= chi_square_test_alpha();
  // TALLY_CHI2_VERBOSE=1 prints every result, to see how far from alpha' tests pass.
  if (std::getenv("TALLY_CHI2_VERBOSE") != nullptr) {
    std::printf("  [chi2] %s: %s\n",
                ::testing::UnitTest::GetInstance()->current_test_info()->name(),
                r.summary().c_str());
  }
  if (ok) return ::testing::AssertionSuccess() << r.summary();
  return ::testing::AssertionFailure() << r.summary();
}

::testing::AssertionResult rejected_by_chi_square(const ChiSquareResult& r, double factor) {
  if (r.p_value < chi_square_test_alpha() * factor)
    return ::testing::AssertionSuccess() << r.summary();
  return ::testing::AssertionFailure() << "not rejected: " << r.summary();
}

std::vector<double> unit_test_grid(int interior_points) {
  std::vector<double> g{0.0};
  for (int i = 0; i < interior_points; ++i) {
    const double t = interior_points == 1 ? 0.5 : static_cast<double>(i) / (interior_points - 1);
    g.push_back(1e-6 + t * (1.0 - 2e-6));
  }
  g.push_back(std::nextafter(1.0, 0.0));
  return g;
}

}  // namespace tally::test
