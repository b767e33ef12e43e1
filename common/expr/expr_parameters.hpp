#pragma once
// Named parameters of an expression: "exp(-a*x0)" with a = 0.5 becomes
// "exp(-(0.5)*x0)". Binding is a substitution of identifier tokens by parenthesized
// literals that read back as the same double (17 significant digits), so the bound text
// compiles, and is cross-checked against muParser, like any other expression. One
// template with a list of values per parameter is how a vector job integrates one
// function at thousands of parameter values.
#include <string>
#include <string_view>
#include <vector>

namespace tally::expr {

struct Parameter {
  std::string name;
  double value = 0.0;
};

// Throws ExprError (syntax) when the text does not tokenize. Names not in the text are
// allowed (they bind nothing). Names must be valid identifiers that the grammar does not
// reserve (check_parameter_name).
std::string bind_parameters(std::string_view text, const std::vector<Parameter>& parameters);

// Empty if `name` can name a parameter; otherwise why not ("is a function name", ...).
std::string check_parameter_name(std::string_view name);

}  // namespace tally::expr
