#include "common/expr/compiled_expression.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <string>
#include <thread>
#include <vector>

namespace tally {
namespace {

TEST(CompiledExpression, UnitDiskIndicatorExactValues) {
  const auto e = CompiledExpression::compile("x0*x0 + x1*x1 < 1 ? 4 : 0", 2);
  EXPECT_EQ(e.dimensions(), 2u);
  EXPECT_EQ(e.text(), "x0*x0 + x1*x1 < 1 ? 4 : 0");
  struct Case {
    double x, y, want;
  };
  const Case cases[] = {
      {0, 0, 4},     {0.5, 0.5, 4},        {1, 0, 0},       {0, 1, 0},
      {-1, 0, 0},    {0.6, 0.8, 0},  // 0.36 + 0.64 rounds to exactly 1: on the circle, outside
      {0.7, 0.7, 4}, {0.8, 0.7, 0},        {-0.99, 0.1, 4}, {1e-300, -1e-300, 4},
      {2, 2, 0},     {std::nan(""), 0, 0},  // NaN < 1 is false
  };
  std::vector<double> xs, ys;
  for (const Case& c : cases) {
    const double p[2] = {c.x, c.y};
    EXPECT_EQ(e.evaluate(p), c.want) << c.x << ", " << c.y;
    xs.push_back(c.x);
    ys.push_back(c.y);
  }
  std::vector<double> out(xs.size(), -1);
  const double* cols[2] = {xs.data(), ys.data()};
  e.evaluate_batch(cols, xs.size(), out.data());
  for (size_t i = 0; i < xs.size(); ++i) EXPECT_EQ(out[i], cases[i].want) << i;
}

TEST(CompiledExpression, UnitDiskMeanIsPi) {
  // Midpoint grid over [-1,1]^2: the fraction inside times 4 approaches pi.
  const auto e = CompiledExpression::compile("x0*x0 + x1*x1 < 1 ? 4 : 0", 2);
  constexpr size_t kSide = 1000;
  std::vector<double> xs(kSide), ys(kSide), out(kSide);
  double total = 0;
  for (size_t j = 0; j < kSide; ++j) {
    for (size_t i = 0; i < kSide; ++i) {
      xs[i] = -1 + (static_cast<double>(i) + 0.5) * 2 / kSide;
      ys[i] = -1 + (static_cast<double>(j) + 0.5) * 2 / kSide;
    }
    const double* cols[2] = {xs.data(), ys.data()};
    e.evaluate_batch(cols, kSide, out.data());
    for (double v : out) total += v;
  }
  EXPECT_NEAR(total / (kSide * kSide), M_PI, 1e-3);
}

TEST(CompiledExpression, SpecialValuesAreProducedNotReported) {
  const double zero[1] = {0};
  EXPECT_EQ(CompiledExpression::compile("1/0", 1).evaluate(zero),
            std::numeric_limits<double>::infinity());
  EXPECT_EQ(CompiledExpression::compile("-1/0", 1).evaluate(zero),
            -std::numeric_limits<double>::infinity());
  EXPECT_TRUE(std::isnan(CompiledExpression::compile("0/0", 1).evaluate(zero)));
  EXPECT_EQ(CompiledExpression::compile("1/x0", 1).evaluate(zero),
            std::numeric_limits<double>::infinity());
  EXPECT_TRUE(std::isnan(CompiledExpression::compile("sqrt(x0 - 1)", 1).evaluate(zero)));
  EXPECT_TRUE(std::isnan(CompiledExpression::compile("log(x0 - 1)", 1).evaluate(zero)));
}

TEST(CompiledExpression, MuParserConstantsAndSemantics) {
  const double x[1] = {0};
  // _pi is muParser's (truncated) 3.141592653589, as the GCC-built library defines it.
  EXPECT_EQ(CompiledExpression::compile("_pi", 1).evaluate(x), 3.141592653589);
  EXPECT_EQ(CompiledExpression::compile("_e", 1).evaluate(x), 2.718281828459045);
  EXPECT_EQ(CompiledExpression::compile("-2^2", 1).evaluate(x), -4);
  EXPECT_EQ(CompiledExpression::compile("2^3^2", 1).evaluate(x), 512);
  EXPECT_EQ(CompiledExpression::compile("2^-2", 1).evaluate(x), 0.25);
  EXPECT_EQ(CompiledExpression::compile("2 ^ - 2 ^ 2", 1).evaluate(x), 0.0625);
  EXPECT_EQ(CompiledExpression::compile("2 == 2 < 3", 1).evaluate(x), 1);  // (2==2)<3
  EXPECT_EQ(CompiledExpression::compile("1 || 0 && 0", 1).evaluate(x), 1);
  EXPECT_EQ(CompiledExpression::compile("0 ? 2 : 0 ? 4 : 5", 1).evaluate(x), 5);
  EXPECT_EQ(CompiledExpression::compile("1 ? 0 ? 3 : 4 : 5", 1).evaluate(x), 4);
  EXPECT_EQ(CompiledExpression::compile("rint(2.5) + rint(-2.5)", 1).evaluate(x), 1);  // 3 + -2
  EXPECT_EQ(CompiledExpression::compile("avg(1, 2, 3, 4)", 1).evaluate(x), 2.5);
  EXPECT_EQ(
      CompiledExpression::compile("sum(1, 2, 3) + min(4, 2, 8) + max(1, 9, 3)", 1).evaluate(x), 17);
  EXPECT_EQ(CompiledExpression::compile("1e-400 + 1e3 + .5 + 5.", 1).evaluate(x), 1005.5);
}

TEST(CompiledExpression, ConstantsFoldAway) {
  EXPECT_EQ(CompiledExpression::compile("sin(_pi / 2) * 3 + 1", 0).instruction_count(), 1u);
  EXPECT_EQ(CompiledExpression::compile("x0*x0 + x1*x1 < 1 ? 4 : 0", 2).instruction_count(), 5u);
  EXPECT_EQ(CompiledExpression::compile("1 ? x0 : x1", 2).instruction_count(), 1u);
}

TEST(CompiledExpression, ZeroDimensionsAndLongBatches) {
  const auto c = CompiledExpression::compile("2 * 3", 0);
  EXPECT_EQ(c.evaluate(nullptr), 6);
  const auto e = CompiledExpression::compile("x0 + 2 * x1", 2);
  std::vector<double> a(1000), b(1000), out(1000);
  for (size_t i = 0; i < a.size(); ++i) {
    a[i] = static_cast<double>(i);
    b[i] = -0.5 * static_cast<double>(i) + 1;
  }
  const double* cols[2] = {a.data(), b.data()};
  e.evaluate_batch(cols, a.size(), out.data());  // more than kBatch: chunked internally
  for (size_t i = 0; i < a.size(); ++i) EXPECT_EQ(out[i], 2.0) << i;
}

TEST(CompiledExpression, SixtyFourDimensions) {
  std::string text = "x0";
  for (int v = 1; v < 64; ++v) text += " + " + std::to_string(v) + " * x" + std::to_string(v);
  const auto e = CompiledExpression::compile(text, 64);
  std::vector<double> x(64, 1.0);
  EXPECT_EQ(e.evaluate(x.data()), 64.0 * 63 / 2 + 1);
}

TEST(CompiledExpression, CopiesShareTheProgram) {
  const auto e = CompiledExpression::compile("x0 * 2", 1);
  const CompiledExpression copy = e;
  const double x[1] = {21};
  EXPECT_EQ(copy.evaluate(x), 42);
}

TEST(CompiledExpression, ThreadsEvaluatingTheSameExpressionAgree) {
  const auto e = CompiledExpression::compile(
      "x0*x0 + x1*x1 < 1 ? exp(-x0*x1) * sin(3*x0) : max(x0, x1, 0.5) - sqrt(abs(x1))", 2);
  constexpr size_t kPoints = 1 << 14;
  std::vector<double> xs(kPoints), ys(kPoints);
  for (size_t i = 0; i < kPoints; ++i) {
    xs[i] = std::sin(static_cast<double>(i) * 0.37) * 1.3;
    ys[i] = std::cos(static_cast<double>(i) * 0.11) * 1.3;
  }
  auto work = [&](size_t batch, std::vector<double>& out) {
    out.assign(kPoints, 0);
    for (int rep = 0; rep < 20; ++rep) {
      for (size_t s = 0; s < kPoints; s += batch) {
        const double* cols[2] = {xs.data() + s, ys.data() + s};
        e.evaluate_batch(cols, std::min(batch, kPoints - s), out.data() + s);
      }
    }
  };
  std::vector<double> a, b, serial;
  std::thread ta(work, 256, std::ref(a));
  std::thread tb(work, 7, std::ref(b));  // different batch size: different scratch use
  ta.join();
  tb.join();
  work(256, serial);
  for (size_t i = 0; i < kPoints; ++i) {
    ASSERT_EQ(a[i], serial[i]) << i;
    ASSERT_EQ(b[i], serial[i]) << i;
    const double p[2] = {xs[i], ys[i]};
    ASSERT_EQ(e.evaluate(p), serial[i]) << i;
  }
}

TEST(CompiledExpression, ThreadsCompilingConcurrentlyAgree) {
  auto work = [](std::vector<double>& out) {
    for (int i = 0; i < 200; ++i) {
      const auto e = CompiledExpression::compile("sin(x0 * " + std::to_string(i) +
                                                     ") + x1 ^ 2 < 0.5 ? avg(x0, x1, " +
                                                     std::to_string(i) + ") : -x0",
                                                 2);
      const double p[2] = {0.25, -0.75};
      out.push_back(e.evaluate(p));
    }
  };
  std::vector<double> a, b;
  std::thread ta(work, std::ref(a));
  std::thread tb(work, std::ref(b));
  ta.join();
  tb.join();
  EXPECT_EQ(a, b);
}

}  // namespace
}  // namespace tally
