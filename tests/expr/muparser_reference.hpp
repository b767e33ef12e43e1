#pragma once
// muParser evaluating the same text over the same variables, for equivalence tests.
#include <muParser.h>

#include <string>
#include <vector>

namespace tally::test {

class MuParserReference {
 public:
  MuParserReference(const std::string& text, size_t dimensions, bool optimizer = false)
      : vars_(dimensions + 1) {
    parser_.EnableOptimizer(optimizer);
    for (size_t v = 0; v < dimensions; ++v) parser_.DefineVar("x" + std::to_string(v), &vars_[v]);
    const char* aliases[] = {"x", "y", "z"};
    for (size_t v = 0; v < dimensions && v < 3; ++v) parser_.DefineVar(aliases[v], &vars_[v]);
    parser_.SetExpr(text);
  }
  double eval(const double* x) {
    for (size_t v = 0; v + 1 < vars_.size(); ++v) vars_[v] = x[v];
    return parser_.Eval();
  }

 private:
  std::vector<double> vars_;
  mu::Parser parser_;
};

// true if muParser accepts the text (with x0..x{d-1}, x, y, z defined).
inline bool muparser_accepts(const std::string& text, size_t dimensions) {
  try {
    MuParserReference ref(text, dimensions);
    std::vector<double> zeros(dimensions + 1, 0.25);
    ref.eval(zeros.data());
    return true;
  } catch (const mu::Parser::exception_type&) {
    return false;
  }
}

}  // namespace tally::test
