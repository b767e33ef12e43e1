#pragma once
// Cross-check of a compiled expression against muParser, the reference implementation.
#include "common/expr/compiled_expression.hpp"

namespace tally::expr {

// Evaluates the expression with muParser (optimizer off, so it computes in the written
// order like our program) at deterministic pseudo-random points of [-1,1]^d and a few
// special points, and compares with `compiled`. Throws ExprError: syntax with muParser's
// message and position if muParser rejects the text; internal if a value differs by more
// than 1e-12 relative (NaN equals NaN).
void check_against_muparser(const CompiledExpression& compiled);

// The comparison used above: equal, both NaN, or within 1e-12 relative.
bool same_value(double ours, double reference);

}  // namespace tally::expr
