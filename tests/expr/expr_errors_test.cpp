// Rejections: every bad expression is an ExprError naming what is wrong and where, and no
// input (deep nesting, huge text) can overflow the stack.
#include <gtest/gtest.h>

#include <string>

#include "common/expr/compiled_expression.hpp"

namespace tally {
namespace {

ExprError compile_error(const std::string& text, size_t dims = 3, const ExprLimits& limits = {}) {
  try {
    CompiledExpression::compile(text, dims, limits);
  } catch (const ExprError& e) {
    return e;
  }
  ADD_FAILURE() << "no error for '" << text << "'";
  return ExprError(ExprErrorKind::internal, "none");
}

void expect_syntax(const std::string& text, size_t position, const std::string& mention,
                   size_t dims = 3) {
  const ExprError e = compile_error(text, dims);
  EXPECT_EQ(e.kind, ExprErrorKind::syntax) << text << ": " << e.what();
  EXPECT_EQ(e.position, position) << text << ": " << e.what();
  EXPECT_NE(std::string(e.what()).find(mention), std::string::npos)
      << text << ": '" << e.what() << "' should mention '" << mention << "'";
}

TEST(ExprErrors, UnbalancedParentheses) {
  expect_syntax("(x0 + 1", 7, "missing ')'");
  expect_syntax("x0 + 1)", 6, "unbalanced ')'");
  expect_syntax("((x0)", 5, "missing ')'");
  expect_syntax("()", 1, "empty parentheses");
  expect_syntax("sin(x0", 6, "missing ')'");
}

TEST(ExprErrors, UnknownVariablesAndFunctions) {
  expect_syntax("x0 + x5", 5, "unknown variable 'x5'");
  expect_syntax("x3", 0, "x0..x2");
  expect_syntax("y", 0, "unknown variable 'y'", 1);
  expect_syntax("x + z", 4, "unknown variable 'z'", 2);
  expect_syntax("x01", 0, "'x01'");
  expect_syntax("X0", 0, "unknown name 'X0'");
  expect_syntax("2 * foo(x0)", 4, "unknown function 'foo'");
  expect_syntax("fmod(x0, 2)", 0, "unknown function 'fmod'");
  expect_syntax("x0(1)", 0, "'x0' is not a function");
  expect_syntax("sin x0", 0, "'sin' needs its arguments");
  expect_syntax("_pi2", 0, "unknown name '_pi2'");
}

TEST(ExprErrors, EmptyExpression) {
  expect_syntax("", 0, "empty");
  expect_syntax("  \t ", 0, "empty");
}

TEST(ExprErrors, MalformedSyntax) {
  expect_syntax("x0 +", 4, "end of the expression");
  expect_syntax("* x0", 0, "unexpected operator '*'");
  expect_syntax("x0 ** 2", 4, "unexpected operator '*'");
  expect_syntax("--x0", 1, "a sign cannot follow a sign");
  expect_syntax("x0 x1", 3, "after a complete expression");
  expect_syntax("2x0", 1, "after a complete expression");
  expect_syntax("x0 ? 1", 6, "no matching ':'");
  expect_syntax("1 : 2", 2, "':'");
  expect_syntax("1e", 0, "malformed number");
  expect_syntax("1e400", 0, "out of range");
  expect_syntax("x0 = 1", 3, "assignment");
  expect_syntax("1, 2", 1, "','");
  expect_syntax("x0 < = 1", 5, "assignment");
  expect_syntax("x0 & x1", 3, "unexpected character '&'");
  expect_syntax("\"abc\"", 0, "string");
  expect_syntax("sin(x0, x1)", 0, "takes 1 argument, got 2");
  expect_syntax("atan2(x0)", 0, "takes 2 arguments, got 1");
  expect_syntax("sum()", 4, "at least one argument");
  expect_syntax("min(x0,)", 7, "unexpected ')'");
  expect_syntax("x0 + \xc3\xa9", 5, "ASCII");
  // The byte in hex (it printed as decimal after "0x": "0x195").
  expect_syntax("x0 + \xc3\xa9", 5, "unexpected byte 0xc3 ");
  expect_syntax("\x7f", 0, "unexpected byte 0x7f ");
  expect_syntax("\x01", 0, "unexpected byte 0x01 ");
}

TEST(ExprErrors, TenThousandNestedParenthesesAreALimitNotACrash) {
  const std::string deep = std::string(10000, '(') + "x0" + std::string(10000, ')');
  ExprError e = compile_error(deep);
  EXPECT_EQ(e.kind, ExprErrorKind::limit) << e.what();  // too long
  ExprLimits generous;
  generous.max_length = 1 << 20;
  e = compile_error(deep, 3, generous);
  EXPECT_EQ(e.kind, ExprErrorKind::limit) << e.what();
  EXPECT_NE(std::string(e.what()).find("nested too deeply"), std::string::npos) << e.what();
  EXPECT_EQ(e.position, 64u);
  generous.max_depth = 1'000'000'000;  // capped internally
  e = compile_error(deep, 3, generous);
  EXPECT_EQ(e.kind, ExprErrorKind::limit) << e.what();
  // power and ternary chains count as nesting too
  std::string powers = "x0";
  for (int i = 0; i < 10000; ++i) powers += "^x0";
  EXPECT_EQ(compile_error(powers, 3, generous).kind, ExprErrorKind::limit);
  std::string ternaries;
  for (int i = 0; i < 10000; ++i) ternaries += "x0 ? 1 : ";
  ternaries += "0";
  EXPECT_EQ(compile_error(ternaries, 3, generous).kind, ExprErrorKind::limit);
}

TEST(ExprErrors, NestingJustInsideTheLimitCompiles) {
  const std::string ok = std::string(64, '(') + "x0" + std::string(64, ')');
  const double x[1] = {3};
  EXPECT_EQ(CompiledExpression::compile(ok, 1).evaluate(x), 3);
  const std::string too_deep = std::string(65, '(') + "x0" + std::string(65, ')');
  EXPECT_EQ(compile_error(too_deep, 1).kind, ExprErrorKind::limit);
}

TEST(ExprErrors, HundredKilobyteExpression) {
  std::string big = "x0";
  while (big.size() < 100 * 1024) big += " + x1";
  ExprError e = compile_error(big);
  EXPECT_EQ(e.kind, ExprErrorKind::limit) << e.what();
  EXPECT_NE(std::string(e.what()).find("too long"), std::string::npos) << e.what();
  // Allowed by length, the long flat sum still stays within the stack (it is one chain)
  // and hits the instruction limit.
  ExprLimits generous;
  generous.max_length = 1 << 20;
  e = compile_error(big, 3, generous);
  EXPECT_EQ(e.kind, ExprErrorKind::limit) << e.what();
  EXPECT_NE(std::string(e.what()).find("instructions"), std::string::npos) << e.what();
}

TEST(ExprErrors, TooManyDimensions) {
  EXPECT_EQ(compile_error("x0", 65).kind, ExprErrorKind::limit);
}

TEST(ExprErrors, MessageNamesPosition) {
  const ExprError e = compile_error("x0 + x5");
  EXPECT_NE(std::string(e.what()).find("position 5"), std::string::npos) << e.what();
}

}  // namespace
}  // namespace tally
