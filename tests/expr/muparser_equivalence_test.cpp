// Our compiled expressions against muParser, the reference, on a corpus that covers the
// grammar (precedence, signs, ^, ternaries, comparisons, logic) and every function.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include "common/expr/compiled_expression.hpp"
#include "common/expr/muparser_check.hpp"
#include "expr/muparser_reference.hpp"

namespace tally {
namespace {

constexpr size_t kDims = 3;

const char* const kCorpus[] = {
    // the lecture's unit-disk indicator
    "x0*x0 + x1*x1 < 1 ? 4 : 0",
    // arithmetic precedence and associativity
    "x0 + x1 * x2",
    "(x0 + x1) * x2",
    "x0 - x1 - x2",
    "x0 - (x1 - x2)",
    "x0 / x1 / x2",
    "x0 / x1 * x2",
    "x0 * x1 / x2 + x0",
    "1 + 2 * x0 - 3 / x1",
    // signs and powers
    "-x0^2",
    "(-x0)^2",
    "2^-x0",
    "-2^-x0",
    "2^-x0^2",
    "2^3^x0",
    "x0^x1^2",
    "abs(x0)^x1^x2",
    "x0*-x1",
    "x0 - -x1",
    "x0 + +x1",
    "-x0 * x1 + x2",
    "-(x0 + x1)",
    "3 * - x0 ^ 2",
    "x0^2 + x1^3 + x2^4",
    "x0^1",
    "x0^0",
    "x0^-1",
    "x0^0.5",
    "abs(x0)^1.5",
    "2^-3*x0",
    "-x0^-x1*2",
    "+x0^2",
    "x0^2^0.5",
    // comparisons: one precedence level, left to right
    "x0 < x1",
    "x0 > x1",
    "x0 <= x1",
    "x0 >= x1",
    "x0 == x1",
    "x0 != x1",
    "x0 == x0",
    "x0 < x1 == x2 < 0",
    "2 == 2 < x0 + 3",
    "x0 < x1 < x2",
    "x0 + 1 > x1 * 2",
    "-x0 < 0.25",
    "x0 >= 0 != x1 >= 0",
    // logic
    "x0 > 0 && x1 > 0",
    "x0 > 0 || x1 > 0",
    "x0 > 0 || x1 > 0 && x2 > 0",
    "(x0 > 0 || x1 > 0) && x2 > 0",
    "x0 && x1",
    "x0 || 0",
    "x0 < 0 && x1 < 0 || x2 < 0",
    // ternaries
    "x0 > 0 ? x1 : x2",
    "x0 > 0 ? 1 : x1 > 0 ? 2 : 3",
    "x0 > 0 ? x1 > 0 ? 1 : 2 : 3",
    "(x0 > 0 ? 1 : 2) + 10",
    "x0 > 0 ? 1 : 2 + 10",
    "x0 ? 1 : 0",
    "x0 > 0 || x1 > 0 ? x2 : -x2",
    "x0 < 0.5 ? sin(x1) : cos(x2) * 2",
    "1 ? x0 : x1",
    "0 ? x0 : x1",
    "x0 > 0 ? x0 : x0",
    "sum(x0 > 0 ? x1 : 2, 3, x2)",
    // every function
    "sin(x0)",
    "cos(x0)",
    "tan(x0)",
    "asin(x0 * 0.9)",
    "acos(x0 * 0.9)",
    "atan(x0 * 10)",
    "sinh(x0 * 3)",
    "cosh(x0 * 3)",
    "tanh(x0 * 3)",
    "asinh(x0 * 5)",
    "acosh(1 + abs(x0) * 4)",
    "atanh(x0 * 0.9)",
    "log2(abs(x0) + 0.1)",
    "log10(abs(x0) + 0.1)",
    "log(abs(x0) + 0.1)",
    "ln(abs(x0) + 0.1)",
    "exp(x0 * 3)",
    "sqrt(abs(x0))",
    "sign(x0)",
    "rint(x0 * 5)",
    "abs(x0)",
    "atan2(x0, x1)",
    "sqrt(x0)",
    "acosh(x0)",
    "log(x0)",
    // variadic functions
    "min(x0, x1)",
    "max(x0, x1, x2)",
    "min(x0)",
    "max(1, x0, 2)",
    "sum(x0)",
    "sum(x0, x1, x2)",
    "avg(x0, x1)",
    "avg(x0, x1, x2, 1)",
    "min(x0, x1) * max(x1, x2)",
    "sum(x0*x0, x1*x1, x2*x2) <= 1",
    "min(x0, 0/0)",
    "max(0/0, x0)",
    "avg(x0)",
    // constants and literals
    "_pi * x0",
    "_e ^ x0",
    "sin(_pi * x0)",
    "_pi",
    "2 * _pi + x0",
    "1e-3 * x0",
    "1.5e+2 * x0",
    ".5 * x0",
    "5. + x0",
    "1E2 - x0",
    "00012 * x0",
    "4",
    "-4",
    // aliases and plain variables
    "x + y + z",
    "x * y - z",
    "x2",
    "-x1",
    // special values
    "1/x0",
    "x0/0",
    "0/0 + x0",
    "sqrt(-1) * x0",
    "-1/0 * x0",
    // folding must not reassociate
    "(x0 + 1) + 2 + 3",
    "1 + 2 + x0",
    "x0 * 2 * 3",
    "x0 + 1e16 - 1e16",
    // bigger integrands
    "exp(-(x0*x0 + x1*x1))",
    "sin(x0)^2 + cos(x0)^2",
    "x0*x0 + x1*x1 + x2*x2 < 1 ? 1 : 0",
    "abs(x0 - x1) < 0.5 && abs(x1 - x2) < 0.5 ? exp(x0*x1*x2) : sign(x2) * log(1 + x0*x0)",
};

// Deterministic points in structure-of-arrays layout: special values first, then
// pseudo-random ones in [-2, 2]^3.
struct Points {
  size_t count = 0;
  std::vector<std::vector<double>> columns;

  explicit Points(size_t n) : count(n), columns(kDims, std::vector<double>(n)) {
    const double specials[] = {0.0, -0.0, 1.0, -1.0, 0.5, -0.5, 2.0, -2.0, 1e-300, 3.0};
    uint64_t state = 12345;
    for (size_t p = 0; p < n; ++p) {
      for (size_t v = 0; v < kDims; ++v) {
        if (p < 1000 && p / 10 < std::size(specials)) {
          // all combinations of a few specials per variable
          const size_t idx = (v == 0 ? p % 10 : v == 1 ? (p / 10) % 10 : (p * 7 + 3) % 10);
          columns[v][p] = specials[idx];
        } else {
          state = state * 6364136223846793005ULL + 1442695040888963407ULL;
          columns[v][p] = static_cast<double>(state >> 11) * 0x1.0p-53 * 4.0 - 2.0;
        }
      }
    }
  }
  std::vector<double> point(size_t p) const {
    std::vector<double> x(kDims);
    for (size_t v = 0; v < kDims; ++v) x[v] = columns[v][p];
    return x;
  }
};

class Equivalence : public ::testing::TestWithParam<const char*> {};

TEST_P(Equivalence, MatchesMuParserInEveryBatchSize) {
  const std::string text = GetParam();
  const CompiledExpression e = CompiledExpression::compile(text, kDims);
  test::MuParserReference ref(text, kDims);
  const Points pts(700);

  std::vector<double> expected(pts.count);
  for (size_t p = 0; p < pts.count; ++p) expected[p] = ref.eval(pts.point(p).data());

  for (size_t batch : {size_t{1}, size_t{7}, size_t{256}, size_t{700}}) {
    std::vector<double> got(pts.count);
    for (size_t start = 0; start < pts.count; start += batch) {
      const size_t n = std::min(batch, pts.count - start);
      const double* xs[kDims];
      for (size_t v = 0; v < kDims; ++v) xs[v] = pts.columns[v].data() + start;
      e.evaluate_batch(xs, n, got.data() + start);
    }
    for (size_t p = 0; p < pts.count; ++p) {
      ASSERT_TRUE(expr::same_value(got[p], expected[p]))
          << text << " batch " << batch << " at (" << pts.columns[0][p] << ", " << pts.columns[1][p]
          << ", " << pts.columns[2][p] << "): ours " << got[p] << ", muParser " << expected[p];
    }
  }
  for (size_t p = 0; p < pts.count; ++p) {
    const double got = e.evaluate(pts.point(p).data());
    ASSERT_TRUE(expr::same_value(got, expected[p])) << text << " evaluate() at point " << p;
  }
}

INSTANTIATE_TEST_SUITE_P(Corpus, Equivalence, ::testing::ValuesIn(kCorpus));

TEST(EquivalenceCorpus, IsLargeEnough) {
  EXPECT_GE(std::size(kCorpus), 60u);
}

// muParser's optimizer (x^2 -> x*x, constant folding) must agree too, within tolerance.
TEST(Equivalence, MatchesOptimizedMuParser) {
  const Points pts(300);
  for (const char* text : kCorpus) {
    const CompiledExpression e = CompiledExpression::compile(text, kDims);
    test::MuParserReference ref(text, kDims, /*optimizer=*/true);
    for (size_t p = 0; p < pts.count; ++p) {
      const auto x = pts.point(p);
      const double want = ref.eval(x.data());
      const double got = e.evaluate(x.data());
      if (std::string(text) == "x0 + 1e16 - 1e16") continue;  // optimizer reassociates
      ASSERT_TRUE(expr::same_value(got, want))
          << text << " at point " << p << ": " << got << " vs " << want;
    }
  }
}

}  // namespace
}  // namespace tally
