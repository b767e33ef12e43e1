#pragma once
// User integrands: muParser-syntax expressions over x0..x{d-1} (aliases x, y, z), compiled
// to a register program that evaluates batches of points in structure-of-arrays layout.
// muParser 2.3 is the reference: compile() cross-checks the program against it and rejects
// what muParser rejects. Grammar and semantics: expr_parser.hpp and expr_ops.hpp.
#include <cstddef>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "common/expr/expr_error.hpp"

namespace tally {

namespace expr {
struct Program;
struct SharedPrograms;
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

  friend class CompiledExpressionSet;
  std::string text_;
  size_t dimensions_ = 0;
  std::shared_ptr<const expr::Program> program_;  // immutable, shared by copies
};

// Several expressions over the same variables (a vector integrand's components),
// evaluated together: what two or more of them compute alike — the same operation on the
// same operands, e.g. the sum of sines in exp(s*(sin(2*_pi*x0)+...)) at every value of
// s — runs once a batch, and each expression runs only the rest (expr_sharing.hpp).
// Each result is bit-identical to the expression's own evaluate_batch. Immutable and
// thread-safe, like CompiledExpression.
class CompiledExpressionSet {
 public:
  // `exprs` non-empty, all of the same dimensions.
  explicit CompiledExpressionSet(const std::vector<CompiledExpression>& exprs);

  size_t size() const;
  // out[c] gets n results of expression c; no out[c] may overlap the inputs.
  void evaluate_batch(const double* const* xs, size_t n, double* const* out) const;
  // Expressions [first, first + count) only: out[k] gets expression first + k (the shared
  // part is computed once a call, so call with many at a time).
  void evaluate_batch(size_t first, size_t count, const double* const* xs, size_t n, double* const* out) const;
  // Instructions a batch runs together (the shared ones once) and one by one: for tests
  // and benchmarks.
  size_t instructions_together() const;
  size_t instructions_alone() const;

 private:
  std::shared_ptr<const expr::SharedPrograms> shared_;
  size_t alone_ = 0;
};

}  // namespace tally
