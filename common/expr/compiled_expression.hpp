#pragma once
// User integrands: muParser-syntax expressions over x0..x{d-1} (aliases x, y, z), compiled
// to a register program that evaluates batches of points in structure-of-arrays layout.
// muParser 2.3 is the reference: compile() cross-checks the program against it and rejects
// what muParser rejects. Grammar and semantics: expr_parser.hpp and expr_ops.hpp.
#include <cstddef>
#include <memory>
#include <string>
#include <string_view>

#include "common/expr/expr_error.hpp"

namespace tally {

namespace expr {
struct Program;
}

class CompiledExpression {
 public:
  static constexpr size_t kMaxDimensions = 64;
  static constexpr size_t kBatch = 256;

  // Throws ExprError: kind syntax (with the character position) for invalid text or text
  // muParser rejects, limit for ExprLimits or dimensions > kMaxDimensions, internal if the
  // compiled program disagrees with muParser.
  static CompiledExpression compile(std::string_view text, size_t dimensions,
                                    const ExprLimits& limits = {});

  size_t dimensions() const { return dimensions_; }
  const std::string& text() const { return text_; }

  // xs[v] points to n values of variable v; writes n results to out (any n; batches of
  // kBatch internally). out must not overlap the inputs. Thread-safe: the scratch space is
  // thread_local. NaN and Inf results are produced, never reported.
  void evaluate_batch(const double* const* xs, size_t n, double* out) const;

  // One point, x[0..d-1].
  double evaluate(const double* x) const;

  // Number of instructions of the compiled program (for tests and the plan's cost model).
  size_t instruction_count() const;

 private:
  CompiledExpression(std::string text, size_t dimensions,
                     std::shared_ptr<const expr::Program> program);

  std::string text_;
  size_t dimensions_ = 0;
  std::shared_ptr<const expr::Program> program_;  // immutable, shared by copies
};

}  // namespace tally
