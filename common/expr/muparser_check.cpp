#include "common/expr/muparser_check.hpp"

#include <muParser.h>

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <string>
#include <vector>

#include "common/expr/expr_error.hpp"

namespace tally::expr {
namespace {

uint64_t splitmix(uint64_t& state) {
  uint64_t z = (state += 0x9e3779b97f4a7c15ULL);
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
  return z ^ (z >> 31);
}

std::string format_double(double v) {
  char buf[40];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  return buf;
}

}  // namespace

bool same_value(double ours, double reference) {
  if (ours == reference) return true;
  if (std::isnan(ours) && std::isnan(reference)) return true;
  if (!std::isfinite(ours) || !std::isfinite(reference)) return false;
  return std::fabs(ours - reference) <= 1e-12 * std::max(std::fabs(ours), std::fabs(reference));
}

void check_against_muparser(const CompiledExpression& compiled) {
  const size_t d = compiled.dimensions();
  constexpr size_t kRandomPoints = 12;
  const double specials[] = {0.0, 0.5, -0.5, 1.0, -1.0};
  const size_t points = kRandomPoints + std::size(specials);

  // Points in structure-of-arrays layout: column v holds variable v at every point.
  std::vector<std::vector<double>> columns(d, std::vector<double>(points));
  uint64_t state = 0x7a11e5eed0000000ULL;
  for (size_t p = 0; p < points; ++p) {
    for (size_t v = 0; v < d; ++v) {
      columns[v][p] = p < std::size(specials)
                          ? specials[p]
                          : static_cast<double>(splitmix(state) >> 11) * 0x1.0p-52 - 1.0;
    }
  }
  std::vector<const double*> xs(d);
  for (size_t v = 0; v < d; ++v) xs[v] = columns[v].data();
  std::vector<double> ours(points);
  compiled.evaluate_batch(xs.data(), points, ours.data());

  std::vector<double> vars(std::max<size_t>(d, 1));
  mu::Parser parser;
  try {
    parser.EnableOptimizer(false);
    for (size_t v = 0; v < d; ++v) parser.DefineVar("x" + std::to_string(v), &vars[v]);
    const char* aliases[] = {"x", "y", "z"};
    for (size_t v = 0; v < std::min<size_t>(d, 3); ++v) parser.DefineVar(aliases[v], &vars[v]);
    parser.SetExpr(compiled.text());
    for (size_t p = 0; p < points; ++p) {
      for (size_t v = 0; v < d; ++v) vars[v] = columns[v][p];
      const double reference = parser.Eval();
      if (!same_value(ours[p], reference)) {
        std::string at;
        for (size_t v = 0; v < d; ++v) at += (v ? ", " : "") + format_double(vars[v]);
        throw ExprError(ExprErrorKind::internal,
                        "internal error: compiled expression '" + compiled.text() + "' gives " +
                            format_double(ours[p]) + " but muParser gives " +
                            format_double(reference) + " at (" + at + ")");
      }
    }
  } catch (const mu::Parser::exception_type& e) {
    const int pos = e.GetPos();
    throw ExprError(ExprErrorKind::syntax, "muParser: " + e.GetMsg(),
                    pos < 0 ? ExprError::npos : static_cast<size_t>(pos));
  }
}

}  // namespace tally::expr
