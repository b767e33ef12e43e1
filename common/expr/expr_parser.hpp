#pragma once
// Recursive-descent parser for muParser's expression grammar, lowest precedence first:
//
//   expression := or ('?' expression ':' expression)?          right-associative
//   or         := and ('||' and)*
//   and        := cmp ('&&' cmp)*
//   cmp        := sum (('<' | '>' | '<=' | '>=' | '==' | '!=') sum)*   one level, left to right
//   sum        := product (('+' | '-') product)*
//   product    := signed (('*' | '/') signed)*
//   signed     := ('-' | '+')? power          a sign never follows a sign: "--2" is an error
//   power      := primary ('^' signed)?        right-associative: -2^2 = -4, 2^-3^2 = 2^-(9)
//   primary    := number | _pi | _e | variable | function '(' args ')' | '(' expression ')'
//
// Variables are x0..x{d-1} and the aliases x, y, z for x0, x1, x2 (when d is large enough).
// Variadic sum/avg/min/max are lowered to chains with muParser's left fold.
#include <cstddef>
#include <string_view>

#include "common/expr/expr_ast.hpp"

namespace tally::expr {

// Throws ExprError (syntax for bad text, limit when nesting exceeds max_depth).
Ast parse(std::string_view text, size_t dimensions, size_t max_depth);

// Replaces every subtree without variables by its value, computed exactly as at run time
// (same functions, same order), so folding never changes a result.
void fold_constants(Ast& ast);

// True for the names the grammar gives a meaning: functions, _pi, _e, and what reads as a
// variable (x, y, z, x<digits>). Such names cannot be bound as parameters.
bool is_reserved_name(std::string_view name);

}  // namespace tally::expr
