#include "common/expr/compiled_expression.hpp"

#include <gtest/gtest.h>

namespace tally {
namespace {

TEST(CompiledExpression, UnitDisk) {
  auto e = CompiledExpression::compile("x0*x0 + x1*x1 < 1 ? 4 : 0", 2);
  double p[2] = {0.5, 0.5};
  EXPECT_EQ(e.evaluate(p), 4.0);
}

}  // namespace
}  // namespace tally
