// Randomized agreement with muParser: grammar-generated expressions must compile and match
// muParser's values; random token soup must be accepted exactly when muParser accepts it
// (apart from muParser-only features we reject on purpose) and never cause an internal error.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <optional>
#include <string>
#include <vector>

#include "common/expr/compiled_expression.hpp"
#include "common/expr/expr_error.hpp"
#include "common/expr/expr_parser.hpp"
#include "common/expr/muparser_check.hpp"
#include "expr/muparser_reference.hpp"

namespace tally {
namespace {

class Rng {
 public:
  explicit Rng(uint64_t seed) : state_(seed) {}
  uint64_t next() {
    uint64_t z = (state_ += 0x9e3779b97f4a7c15ULL);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
    return z ^ (z >> 31);
  }
  size_t below(size_t n) { return static_cast<size_t>(next() % n); }
  double uniform(double lo, double hi) {
    return lo + (hi - lo) * static_cast<double>(next() >> 11) * 0x1.0p-53;
  }
  template <class T, size_t N>
  const T& pick(const T (&items)[N]) {
    return items[below(N)];
  }

 private:
  uint64_t state_;
};

// Generates text following the grammar of expr_parser.hpp, with random spacing.
class Generator {
 public:
  explicit Generator(Rng& rng) : rng_(rng) {}

  std::string expression(int depth) {
    std::string c = logic(depth);
    if (depth > 0 && rng_.below(6) == 0) {
      return c + sp() + "?" + sp() + expression(depth - 1) + sp() + ":" + sp() +
             expression(depth - 1);
    }
    return c;
  }

 private:
  std::string sp() { return rng_.below(3) == 0 ? " " : ""; }

  template <class Sub, size_t N>
  std::string chain(int depth, Sub sub, const char* const (&ops)[N], size_t max_terms) {
    std::string s = (this->*sub)(depth);
    const size_t extra = rng_.below(max_terms);
    for (size_t i = 0; i < extra; ++i) {
      s += sp() + rng_.pick(ops) + sp() + (this->*sub)(depth > 0 ? depth - 1 : 0);
    }
    return s;
  }
  std::string logic(int d) {
    static const char* const ops[] = {"&&", "||"};
    return chain(d, &Generator::compare, ops, rng_.below(4) == 0 ? 3 : 1);
  }
  std::string compare(int d) {
    static const char* const ops[] = {"<", ">", "<=", ">=", "==", "!="};
    return chain(d, &Generator::sum, ops, rng_.below(3) == 0 ? 3 : 1);
  }
  std::string sum(int d) {
    static const char* const ops[] = {"+", "-"};
    return chain(d, &Generator::product, ops, 4);
  }
  std::string product(int d) {
    static const char* const ops[] = {"*", "/"};
    return chain(d, &Generator::signed_power, ops, 3);
  }
  std::string signed_power(int d) {
    const size_t r = rng_.below(8);
    const std::string sign = r == 0 ? "-" : r == 1 ? "+" : "";
    return sign + sp() + power(d);
  }
  std::string power(int d) {
    std::string base = primary(d);
    if (d > 0 && rng_.below(6) == 0) return base + sp() + "^" + sp() + signed_power(d - 1);
    return base;
  }
  std::string primary(int d) {
    static const char* const vars[] = {"x0", "x1", "x2", "x", "y", "z"};
    static const char* const literals[] = {"0",  "1",  "2",   "3",   "0.5", "1e-3", "3.25",
                                           ".5", "5.", "1E2", "_pi", "_e",  "10",   "0.1"};
    static const char* const unary[] = {"sin",  "cos",  "tan",   "asin",  "acos",  "atan", "sinh",
                                        "cosh", "tanh", "asinh", "acosh", "atanh", "log2", "log10",
                                        "log",  "ln",   "exp",   "sqrt",  "sign",  "rint", "abs"};
    static const char* const variadic[] = {"min", "max", "sum", "avg"};
    const size_t r = d > 0 ? rng_.below(10) : rng_.below(2);
    switch (r) {
      case 0:
        return rng_.pick(vars);
      case 1:
        return rng_.pick(literals);
      case 2:
      case 3:
        return "(" + sp() + expression(d - 1) + sp() + ")";
      case 4:
      case 5:
        return std::string(rng_.pick(unary)) + "(" + expression(d - 1) + ")";
      case 6:
        return "atan2(" + expression(d - 1) + "," + sp() + expression(d - 1) + ")";
      case 7: {
        std::string s = std::string(rng_.pick(variadic)) + "(" + expression(d - 1);
        const size_t more = rng_.below(4);
        for (size_t i = 0; i < more; ++i) s += "," + sp() + expression(d - 1);
        return s + ")";
      }
      default:
        return rng_.pick(vars);
    }
  }

  Rng& rng_;
};

// Every generated expression compiles and agrees with muParser at 40 random points.
// Agreement is counted by kind: both finite and within 1e-12 relative, both NaN, or the
// same infinity. A NaN from one side only is a mismatch. Most comparisons must be of
// finite values (issue 27: NaN = NaN everywhere would otherwise pass unnoticed).
TEST(ExprFuzz, GeneratedExpressionsMatchMuParser) {
  Rng rng(2024);
  Generator gen(rng);
  int compiled = 0;
  size_t finite = 0, both_nan = 0, same_inf = 0;
  for (int i = 0; i < 3000; ++i) {
    std::string text = gen.expression(static_cast<int>(rng.below(5)));
    while (text.size() > 2000) text = gen.expression(2);
    std::optional<CompiledExpression> e;
    try {
      e = CompiledExpression::compile(text, 3);
    } catch (const ExprError& err) {
      FAIL() << "'" << text << "' rejected: " << err.what();
    }
    ++compiled;
    test::MuParserReference ref(text, 3);
    for (int p = 0; p < 40; ++p) {
      const double x[3] = {rng.uniform(-3, 3), rng.uniform(-3, 3), rng.uniform(-3, 3)};
      const double want = ref.eval(x);
      const double got = e->evaluate(x);
      const std::string where = text + " at (" + std::to_string(x[0]) + ", " + std::to_string(x[1]) + ", " +
                                std::to_string(x[2]) + ")";
      ASSERT_EQ(std::isnan(got), std::isnan(want)) << where << ": ours " << got << ", muParser " << want;
      if (std::isnan(got)) {
        ++both_nan;
      } else if (std::isinf(got) || std::isinf(want)) {
        ASSERT_EQ(got, want) << where;
        ++same_inf;
      } else {
        ASSERT_LE(std::fabs(got - want), 1e-12 * std::max(std::fabs(got), std::fabs(want))) << where << ": ours "
                                                                                              << got << ", muParser "
                                                                                              << want;
        ++finite;
      }
    }
  }
  EXPECT_EQ(compiled, 3000);
  const size_t total = finite + both_nan + same_inf;
  std::printf("comparisons: %zu finite, %zu both NaN, %zu same infinity\n", finite, both_nan, same_inf);
  EXPECT_EQ(total, 3000u * 40u);
  // Measured: about 2/3 finite (the generator's asin, acos, log, sqrt of values in
  // [-3, 3] give NaN often). Fewer than half would mean the check compares little.
  EXPECT_GT(finite, total / 2);
}

TEST(ExprFuzz, TokenSoupIsAcceptedExactlyWhenMuParserAcceptsIt) {
  static const char* const tokens[] = {"x0",  "x1",    "y", "1", "2.5", "_pi", "+",   "-",
                                       "*",   "/",     "^", "<", "<=",  "==",  "!=",  "&&",
                                       "||",  "?",     ":", "(", ")",   ",",   "sin", "min",
                                       "sum", "atan2", "(", ")", "x0",  "1",   "-",   " "};
  Rng rng(77);
  int accepted = 0;
  for (int i = 0; i < 20000; ++i) {
    std::string text;
    const size_t count = 1 + rng.below(10);
    for (size_t t = 0; t < count; ++t) text += rng.pick(tokens);
    bool ours = true;
    try {
      CompiledExpression::compile(text, 2);
    } catch (const ExprError& err) {
      ASSERT_NE(err.kind, ExprErrorKind::internal) << text << ": " << err.what();
      ours = false;
      // A rejection by muParser after our parser accepted would mean our grammar is wider.
      ASSERT_EQ(std::string(err.what()).rfind("muParser:", 0), std::string::npos)
          << "'" << text << "' passed our parser but muParser rejects it: " << err.what();
    }
    const bool reference = test::muparser_accepts(text, 2);
    if (ours) {
      ++accepted;
      ASSERT_TRUE(reference) << "'" << text << "'";
    } else if (reference) {
      // Only muParser's comma-separated multiple results are rejected on purpose.
      ASSERT_NE(text.find(','), std::string::npos)
          << "'" << text << "' is valid muParser but we reject it";
    }
  }
  EXPECT_GT(accepted, 100);
}

}  // namespace
}  // namespace tally
