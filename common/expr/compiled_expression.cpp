#include "common/expr/compiled_expression.hpp"

#include <algorithm>
#include <utility>

#include "common/expr/expr_parser.hpp"
#include "common/expr/expr_program.hpp"
#include "common/expr/expr_sharing.hpp"
#include "common/expr/muparser_check.hpp"

namespace tally {

static_assert(CompiledExpression::kBatch == expr::kBatch);

namespace {
// Each nesting level costs about ten parser frames; this keeps the worst case far below
// the smallest thread stack we run on, whatever ExprLimits asks for.
constexpr size_t kDepthCeiling = 256;
}  // namespace

CompiledExpression::CompiledExpression(std::string text, size_t dimensions,
                                       std::shared_ptr<const expr::Program> program)
    : text_(std::move(text)), dimensions_(dimensions), program_(std::move(program)) {}

CompiledExpression CompiledExpression::compile(std::string_view text, size_t dimensions,
                                               const ExprLimits& limits) {
  if (dimensions > kMaxDimensions) {
    throw ExprError(ExprErrorKind::limit, "expressions support at most " +
                                              std::to_string(kMaxDimensions) + " dimensions, got " +
                                              std::to_string(dimensions));
  }
  if (text.size() > limits.max_length) {
    throw ExprError(ExprErrorKind::limit,
                    "expression is too long: " + std::to_string(text.size()) +
                        " characters, limit " + std::to_string(limits.max_length),
                    limits.max_length);
  }
  expr::Ast ast = expr::parse(text, dimensions, std::min(limits.max_depth, kDepthCeiling));
  expr::fold_constants(ast);
  auto program = std::make_shared<const expr::Program>(
      expr::generate(ast, dimensions, limits.max_instructions));
  CompiledExpression compiled(std::string(text), dimensions, std::move(program));
  expr::check_against_muparser(compiled);
  return compiled;
}

void CompiledExpression::evaluate_batch(const double* const* xs, size_t n, double* out) const {
  if (n <= kBatch) {
    expr::run_batch(*program_, xs, n, out);
    return;
  }
  const double* shifted[kMaxDimensions];
  for (size_t start = 0; start < n; start += kBatch) {
    for (size_t v = 0; v < dimensions_; ++v) shifted[v] = xs[v] + start;
    expr::run_batch(*program_, shifted, std::min(kBatch, n - start), out + start);
  }
}

double CompiledExpression::evaluate(const double* x) const {
  return expr::run_point(*program_, x);
}

size_t CompiledExpression::instruction_count() const {
  return program_->code.size();
}

CompiledExpressionSet::CompiledExpressionSet(const std::vector<CompiledExpression>& exprs) {
  std::vector<std::shared_ptr<const expr::Program>> programs;
  programs.reserve(exprs.size());
  for (const CompiledExpression& e : exprs) {
    programs.push_back(e.program_);
    alone_ += e.program_->code.size();
  }
  shared_ = std::make_shared<const expr::SharedPrograms>(expr::share_programs(programs));
}

size_t CompiledExpressionSet::size() const { return shared_->size(); }

void CompiledExpressionSet::evaluate_batch(const double* const* xs, size_t n, double* const* out) const {
  expr::run_shared(*shared_, 0, size(), xs, n, out);
}

void CompiledExpressionSet::evaluate_batch(size_t first, size_t count, const double* const* xs, size_t n,
                                           double* const* out) const {
  expr::run_shared(*shared_, first, count, xs, n, out);
}

size_t CompiledExpressionSet::instructions_together() const {
  if (!shared_->alone.empty()) return alone_;
  size_t total = shared_->prelude.code.size();
  for (const expr::Program& r : shared_->residual) total += r.code.size();
  return total;
}

size_t CompiledExpressionSet::instructions_alone() const { return alone_; }

}  // namespace tally
