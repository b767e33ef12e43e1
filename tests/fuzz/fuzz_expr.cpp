// libFuzzer: the expression compiler. Oracles: muParser (compile() cross-checks the
// compiled program against it and throws kind internal on a disagreement), the scalar
// path against the batch path, and the expression evaluated in a set with two that
// share its program (CompiledExpressionSet) against it alone, bit for bit.
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <optional>
#include <string>
#include <vector>

#include "common/expr/compiled_expression.hpp"
#include "common/expr/expr_error.hpp"
#include "fuzz_support.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size < 1) return 0;
  const size_t dims = 1 + data[0] % 4;
  const std::string text(reinterpret_cast<const char*>(data) + 1, size - 1);
  using tally::CompiledExpression;
  std::optional<CompiledExpression> e;
  try {
    e.emplace(CompiledExpression::compile(text, dims));
  } catch (const tally::ExprError& err) {
    if (err.kind == tally::ExprErrorKind::internal) tally::fuzz::fail("internal error", err.what(), text);
    return 0;
  }
  // Scalar and batch paths agree bit for bit (NaN equals NaN) at a few points.
  const double pts[] = {0.0, -0.0, 0.5, -1.0, 1e-300, 3.0, -2.5, 1e300};
  constexpr size_t kN = 8;
  std::vector<std::vector<double>> cols(dims, std::vector<double>(kN));
  std::vector<const double*> xs(dims);
  for (size_t v = 0; v < dims; ++v) {
    for (size_t i = 0; i < kN; ++i) cols[v][i] = pts[(i + 3 * v) % kN];
    xs[v] = cols[v].data();
  }
  double batch[kN];
  e->evaluate_batch(xs.data(), kN, batch);
  for (size_t i = 0; i < kN; ++i) {
    double x[4];
    for (size_t v = 0; v < dims; ++v) x[v] = cols[v][i];
    const double scalar = e->evaluate(x);
    const bool same = (std::isnan(scalar) && std::isnan(batch[i])) ||
                      std::memcmp(&scalar, &batch[i], sizeof(double)) == 0;
    if (!same) tally::fuzz::fail("scalar and batch differ", std::to_string(scalar) + " vs " + std::to_string(batch[i]), text);
  }
  // In a set with (text)*x0 and x0 (each shares its program or a part of it): every
  // member's result is its own, bit for bit (a NaN's payload included).
  std::vector<CompiledExpression> set_members = {*e};
  try {
    set_members.push_back(CompiledExpression::compile("(" + text + ")*x0", dims));
  } catch (const tally::ExprError& err) {
    if (err.kind == tally::ExprErrorKind::internal) tally::fuzz::fail("internal error", err.what(), text);
  }
  set_members.push_back(CompiledExpression::compile("x0", dims));
  const tally::CompiledExpressionSet set(set_members);
  std::vector<std::vector<double>> together(set_members.size(), std::vector<double>(kN));
  std::vector<double*> outs;
  for (auto& o : together) outs.push_back(o.data());
  set.evaluate_batch(xs.data(), kN, outs.data());
  for (size_t c = 0; c < set_members.size(); ++c) {
    double alone[kN];
    set_members[c].evaluate_batch(xs.data(), kN, alone);
    if (std::memcmp(alone, together[c].data(), sizeof(alone)) != 0) {
      tally::fuzz::fail("a set member differs from itself alone", set_members[c].text(), text);
    }
  }
  return 0;
}
