#pragma once
// The operations of the expression language and their scalar meaning, written exactly as
// muParser 2.3.3 computes them (MathImpl in muParserTemplateMagic.h, and the cmLT/cmLAND/...
// cases of ParserBase::ParseCmdCode), so constant folding, the batch kernels and muParser
// agree to the last bit. Note muParser's own formulas for asinh/acosh/atanh/log2/rint/abs:
// they are the reference semantics, not std::asinh etc.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <string_view>

namespace tally::expr {

enum class Op : uint8_t {
  // binary
  add,
  sub,
  mul,
  div,
  pow,
  lt,
  gt,
  le,
  ge,
  eq,
  ne,
  land,
  lor,
  min2,
  max2,
  atan2,
  // unary
  neg,
  sin,
  cos,
  tan,
  asin,
  acos,
  atan,
  sinh,
  cosh,
  tanh,
  asinh,
  acosh,
  atanh,
  log2,
  log10,
  ln,
  exp,
  sqrt,
  sign,
  rint,
  abs,
  // other
  select,  // cond ? a : b
  copy,    // dst = a
};

constexpr bool is_binary(Op op) {
  return op <= Op::atan2;
}
constexpr bool is_unary(Op op) {
  return op >= Op::neg && op <= Op::abs;
}

constexpr double from_bool(bool b) {
  return b ? 1.0 : 0.0;
}

// Binary operations. min2/max2 are one step of muParser's Min/Max fold:
// r = std::min(r, a) == (a < r ? a : r) and r = std::max(r, a) == (r < a ? a : r).
[[gnu::always_inline]] inline double apply_binary(Op op, double a, double b) {
  switch (op) {
    case Op::add:
      return a + b;
    case Op::sub:
      return a - b;
    case Op::mul:
      return a * b;
    case Op::div:
      return a / b;
    case Op::pow:
      return std::pow(a, b);
    case Op::lt:
      return from_bool(a < b);
    case Op::gt:
      return from_bool(a > b);
    case Op::le:
      return from_bool(a <= b);
    case Op::ge:
      return from_bool(a >= b);
    case Op::eq:
      return from_bool(a == b);
    case Op::ne:
      return from_bool(a != b);
    case Op::land:
      return from_bool((a != 0) & (b != 0));
    case Op::lor:
      return from_bool((a != 0) | (b != 0));
    case Op::min2:
      return b < a ? b : a;
    case Op::max2:
      return a < b ? b : a;
    case Op::atan2:
      return std::atan2(a, b);
    default:
      return std::nan("");
  }
}

[[gnu::always_inline]] inline double apply_unary(Op op, double v) {
  switch (op) {
    case Op::neg:
      return -v;
    case Op::sin:
      return std::sin(v);
    case Op::cos:
      return std::cos(v);
    case Op::tan:
      return std::tan(v);
    case Op::asin:
      return std::asin(v);
    case Op::acos:
      return std::acos(v);
    case Op::atan:
      return std::atan(v);
    case Op::sinh:
      return std::sinh(v);
    case Op::cosh:
      return std::cosh(v);
    case Op::tanh:
      return std::tanh(v);
    case Op::asinh:
      return std::log(v + std::sqrt(v * v + 1));
    case Op::acosh:
      return std::log(v + std::sqrt(v * v - 1));
    case Op::atanh:
      return 0.5 * std::log((1 + v) / (1 - v));
    case Op::log2:
      return std::log(v) / std::log(2.0);
    case Op::log10:
      return std::log10(v);
    case Op::ln:
      return std::log(v);
    case Op::exp:
      return std::exp(v);
    case Op::sqrt:
      return std::sqrt(v);
    case Op::sign:
      return v < 0 ? -1.0 : (v > 0 ? 1.0 : 0.0);
    case Op::rint:
      return std::floor(v + 0.5);
    case Op::abs:
      return v >= 0 ? v : -v;
    default:
      return std::nan("");
  }
}

constexpr double select_value(double cond, double a, double b) {
  return cond != 0 ? a : b;
}

// muParser's constants as the Debian (GCC-built) library defines them: _pi is the
// truncated 3.141592653589 of MathImpl::CONST_PI under __GNUG__, not M_PI.
inline constexpr double kMuParserPi = 3.141592653589;
inline constexpr double kMuParserE = 2.718281828459045235360287;

}  // namespace tally::expr
