#pragma once
// Reusable chi-square goodness-of-fit harness for sampling routines, after Mitsuba 3's
// and pbrt-v4's: draw ~1e6 samples into a fine histogram over a rectangular parameter
// domain, integrate the claimed pdf over each cell for the expected counts, pool cells
// with expected count < 5, and reject at alpha = 0.01 with the Sidak correction over
// every chi-square test of this executable. Also fails when a sample lands where the
// pdf is 0, falls outside the domain, or the pdf does not integrate to 1.
#include <cstddef>
#include <cstdint>
#include <functional>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "common/math/vec3.hpp"

namespace tally::test {

// Number of chi-square tests in tally_sampling_tests that are expected to pass (each call
// of passes_chi_square). The Sidak correction divides the suite's 1% false-alarm budget
// among them; a global check fails the run if the unfiltered suite runs a different
// number (or a filtered run more) than declared here.
inline constexpr int kChiSquareTestCount = 27;
inline constexpr double kChiSquareSuiteAlpha = 0.01;
// alpha' = 1 - (1 - alpha)^(1/N).
double chi_square_test_alpha();

struct ChiSquareOptions {
  std::uint64_t samples = 1'000'000;
  // Midpoint rule: subdivisions^2 points per cell, in 2-D as a square grid, in 1-D all
  // along x (1-D pdfs are cheap and often have steps that need the resolution).
  int subdivisions = 16;
  double min_expected = 5.0;
};

struct Histogram2D {
  double x0, x1;
  double y0, y1;
  int nx, ny;
};

struct ChiSquareResult {
  double statistic = 0;
  int dof = 0;
  double p_value = 0;
  std::uint64_t samples = 0;         // requested
  std::uint64_t failed = 0;          // sampler returned no sample
  std::uint64_t outside = 0;         // sample outside the histogram domain (or NaN)
  std::uint64_t zero_pdf = 0;        // sample where the pdf is 0, negative or not finite
  std::uint64_t zero_cell_hits = 0;  // samples in cells whose integrated pdf is 0
  double pdf_integral = 0;           // over the domain; should be 1
  std::string summary() const;
};

using Sampler2 = std::function<std::optional<Vec2>(std::uint64_t index)>;
using Pdf2 = std::function<double(Vec2)>;
using Sampler1 = std::function<std::optional<double>(std::uint64_t index)>;
using Pdf1 = std::function<double(double)>;
using SamplerDiscrete = std::function<std::size_t(std::uint64_t index)>;

ChiSquareResult chi_square_2d(const Histogram2D& h, const Sampler2& sample, const Pdf2& pdf,
                              const ChiSquareOptions& options = {});
ChiSquareResult chi_square_1d(double x0, double x1, int cells, const Sampler1& sample,
                              const Pdf1& pdf, const ChiSquareOptions& options = {});
ChiSquareResult chi_square_discrete(std::span<const double> probabilities,
                                    const SamplerDiscrete& sample,
                                    const ChiSquareOptions& options = {});
// Pools cells with expected < min_expected and computes statistic, dof and p-value.
void chi_square_from_counts(std::span<const double> expected,
                            std::span<const std::uint64_t> observed, double min_expected,
                            ChiSquareResult& result);

// Every check passes and p >= alpha'. Counts towards kChiSquareTestCount.
::testing::AssertionResult passes_chi_square(const ChiSquareResult& r);
// For deliberately wrong samplers: p-value below alpha' * factor (far below alpha').
::testing::AssertionResult rejected_by_chi_square(const ChiSquareResult& r, double factor);

// Inputs for round-trip tests: 0, a grid from 1e-6 to 1 - 1e-6, and the largest double
// below 1.
std::vector<double> unit_test_grid(int interior_points);

}  // namespace tally::test
