// Expressions evaluated together (CompiledExpressionSet, common/expr/expr_sharing.hpp):
// what they compute alike runs once, and every result is bit for bit what the
// expression computes alone — at every batch size, including partial batches, NaN and
// infinities.
#include <gtest/gtest.h>

#include <cstring>
#include <random>
#include <string>
#include <vector>

#include "common/expr/compiled_expression.hpp"
#include "common/expr/expr_parameters.hpp"

namespace tally {
namespace {

std::vector<CompiledExpression> at_values(const std::string& text, const std::vector<double>& values, size_t d) {
  std::vector<CompiledExpression> out;
  for (double v : values) out.push_back(CompiledExpression::compile(expr::bind_parameters(text, {{"s", v}}), d));
  return out;
}

// Each expression of the set, together and alone, on n points (x in [-1.5, 1.5]^d and a
// few exact zeros, so that divisions, logs and roots give infinities and NaN too).
void expect_bit_identical(const std::vector<CompiledExpression>& exprs, size_t n, uint32_t seed) {
  const size_t d = exprs.front().dimensions();
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-1.5, 1.5);
  std::vector<std::vector<double>> x(d, std::vector<double>(n));
  for (auto& col : x) {
    for (size_t i = 0; i < n; ++i) col[i] = i % 17 == 3 ? 0.0 : u(rng);
  }
  std::vector<const double*> xs;
  for (auto& col : x) xs.push_back(col.data());
  const CompiledExpressionSet set(exprs);
  ASSERT_EQ(set.size(), exprs.size());
  std::vector<std::vector<double>> together(exprs.size(), std::vector<double>(n, -7.0));
  std::vector<double*> out;
  for (auto& o : together) out.push_back(o.data());
  set.evaluate_batch(xs.data(), n, out.data());
  std::vector<double> alone(n);
  for (size_t c = 0; c < exprs.size(); ++c) {
    exprs[c].evaluate_batch(xs.data(), n, alone.data());
    ASSERT_EQ(std::memcmp(alone.data(), together[c].data(), n * sizeof(double)), 0)
        << "expression " << c << " (" << exprs[c].text() << ") at n = " << n;
  }
}

const std::vector<size_t> kSizes = {1, 7, 8, 255, 256, 257, 700};

TEST(ExprSharing, OneTemplateAtManyValuesIsBitIdenticalAtEveryBatchSize) {
  std::vector<double> values;
  for (int i = 0; i < 40; ++i) values.push_back(-1.0 + 0.05 * i);  // includes 0
  const std::vector<std::string> templates = {
      "exp(s*(sin(2*_pi*x0)+0.5*sin(2*_pi*x1)+0.25*cos(x2)))",
      "x0 < s ? sin(x1)*cos(x0) : s*x0^2",
      "atan2(x1, s) + max(x0, x1) - sqrt(x0*x0 + x1*x1)",
      "(x0 + s) * (x0*x1 + 1) / x2 + ln(x0) + s",
      "s",
      "x1",
      "2*x0 + 3",
  };
  for (const std::string& t : templates) {
    const auto exprs = at_values(t, values, 3);
    for (size_t n : kSizes) expect_bit_identical(exprs, n, static_cast<uint32_t>(n));
  }
}

TEST(ExprSharing, DifferentExpressionsShareTheirCommonPart) {
  const std::vector<std::string> texts = {"sqrt(x0*x0+x1*x1)", "exp(-(x0*x0+x1*x1))", "x0*x0+x1*x1 < 1 ? 4 : 0",
                                          "x1", "x0*x0+x1*x1", "1/(x0*x0+x1*x1)"};
  std::vector<CompiledExpression> exprs;
  for (const auto& t : texts) exprs.push_back(CompiledExpression::compile(t, 2));
  for (size_t n : kSizes) expect_bit_identical(exprs, n, 99);
  const CompiledExpressionSet set(exprs);
  EXPECT_LT(set.instructions_together(), set.instructions_alone());
}

// A vector integrand's usual shape: the parameter only at the top. The sixteen sines and
// their weighted sum run once; each of the 1,000 components is left a product and an exp.
TEST(ExprSharing, ATemplateAtAThousandValuesRunsItsSharedPartOnce) {
  std::string sum;
  for (int j = 0; j < 16; ++j) sum += (j ? "+" : "") + std::to_string(1.0 / (j + 1)) + "*sin(2*_pi*x" + std::to_string(j) + ")";
  std::vector<double> values;
  for (int i = 1; i <= 1000; ++i) values.push_back(i / 1000.0);
  const auto exprs = at_values("exp(s*(" + sum + "))", values, 16);
  const CompiledExpressionSet set(exprs);
  const size_t alone = set.instructions_alone(), together = set.instructions_together();
  std::printf("instructions a batch: %zu alone, %zu together\n", alone, together);
  EXPECT_EQ(alone, 1000 * exprs[0].instruction_count());
  EXPECT_LE(together, 2 * 1000 + exprs[0].instruction_count());
  for (size_t n : {size_t{5}, size_t{256}, size_t{300}}) expect_bit_identical(exprs, n, 7);
}

TEST(ExprSharing, ExpressionsWithNothingInCommonRunAlone) {
  const std::vector<CompiledExpression> exprs = {CompiledExpression::compile("x0 + 1", 2),
                                                 CompiledExpression::compile("x1 * 2", 2),
                                                 CompiledExpression::compile("sin(x0) - x1", 2)};
  const CompiledExpressionSet set(exprs);
  EXPECT_EQ(set.instructions_together(), set.instructions_alone());
  for (size_t n : kSizes) expect_bit_identical(exprs, n, 5);
}

TEST(ExprSharing, OneExpressionAloneIsItsOwnProgram) {
  const std::vector<CompiledExpression> one = {CompiledExpression::compile("sin(x0)*x1 + 1", 2)};
  const CompiledExpressionSet set(one);
  EXPECT_EQ(set.instructions_together(), set.instructions_alone());
  for (size_t n : kSizes) expect_bit_identical(one, n, 3);
}

}  // namespace
}  // namespace tally
