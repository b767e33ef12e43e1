// Batch interpreter of a Program: one switch per instruction, then a plain loop over the
// batch. Loops run over blocks of kLane values with a fixed inner trip count so GCC
// vectorizes them even at -O2 (whose cost model refuses loops needing a scalar epilogue);
// a batch whose size is not a multiple of kLane runs on zero-padded copies of its inputs.
#include <algorithm>
#include <cstring>
#include <vector>

#include "common/expr/expr_program.hpp"

namespace tally::expr {
namespace {

constexpr size_t kLane = 8;
static_assert(kBatch % kLane == 0);

template <class F>
[[gnu::always_inline]] inline void map_a(double* __restrict o, const double* __restrict a, size_t n,
                                         F f) {
  for (size_t i = 0; i < n; i += kLane)
    for (size_t j = 0; j < kLane; ++j) o[i + j] = f(a[i + j]);
}
template <class F>
[[gnu::always_inline]] inline void map_ab(double* __restrict o, const double* __restrict a,
                                          const double* __restrict b, size_t n, F f) {
  for (size_t i = 0; i < n; i += kLane)
    for (size_t j = 0; j < kLane; ++j) o[i + j] = f(a[i + j], b[i + j]);
}
template <class F>
[[gnu::always_inline]] inline void map_ak(double* __restrict o, const double* __restrict a,
                                          double k, size_t n, F f) {
  for (size_t i = 0; i < n; i += kLane)
    for (size_t j = 0; j < kLane; ++j) o[i + j] = f(a[i + j], k);
}
template <class F>
[[gnu::always_inline]] inline void map_ka(double* __restrict o, double k,
                                          const double* __restrict b, size_t n, F f) {
  for (size_t i = 0; i < n; i += kLane)
    for (size_t j = 0; j < kLane; ++j) o[i + j] = f(k, b[i + j]);
}

template <Op op>
[[gnu::always_inline]] inline void binary(const Instr& ins, double* __restrict o,
                                          const double* const* slots, size_t n) {
  auto f = [](double x, double y) { return apply_binary(op, x, y); };
  if (ins.const_b) {
    map_ak(o, slots[ins.a], ins.kb, n, f);
  } else if (ins.const_a) {
    map_ka(o, ins.ka, slots[ins.b], n, f);
  } else {
    map_ab(o, slots[ins.a], slots[ins.b], n, f);
  }
}

template <Op op>
[[gnu::always_inline]] inline void unary(const Instr& ins, double* __restrict o,
                                         const double* const* slots, size_t n) {
  map_a(o, slots[ins.a], n, [](double x) { return apply_unary(op, x); });
}

[[gnu::always_inline]] inline void select(const Instr& ins, double* __restrict o,
                                          const double* const* slots, size_t n) {
  const double* __restrict c = slots[ins.c];
  if (ins.const_a && ins.const_b) {
    const double ka = ins.ka, kb = ins.kb;
    map_a(o, c, n, [ka, kb](double x) { return select_value(x, ka, kb); });
  } else if (ins.const_b) {
    const double* __restrict a = slots[ins.a];
    const double kb = ins.kb;
    map_ab(o, c, a, n, [kb](double x, double y) { return select_value(x, y, kb); });
  } else if (ins.const_a) {
    const double* __restrict b = slots[ins.b];
    const double ka = ins.ka;
    map_ab(o, c, b, n, [ka](double x, double y) { return select_value(x, ka, y); });
  } else {
    const double* __restrict a = slots[ins.a];
    const double* __restrict b = slots[ins.b];
    for (size_t i = 0; i < n; i += kLane)
      for (size_t j = 0; j < kLane; ++j) o[i + j] = select_value(c[i + j], a[i + j], b[i + j]);
  }
}

// Cloned for AVX2 (4 doubles a vector instead of SSE2's 2), chosen once at load time. No
// FMA: contraction would change results against muParser.
__attribute__((target_clones("avx2", "default"))) void execute(const Instr& ins,
                                                               double* __restrict o,
                                                               const double* const* slots,
                                                               size_t n) {
  switch (ins.op) {
#define TALLY_EXPR_BINARY(name)         \
  case Op::name:                        \
    binary<Op::name>(ins, o, slots, n); \
    break;
#define TALLY_EXPR_UNARY(name)         \
  case Op::name:                       \
    unary<Op::name>(ins, o, slots, n); \
    break;
    TALLY_EXPR_BINARY(add)
    TALLY_EXPR_BINARY(sub)
    TALLY_EXPR_BINARY(mul)
    TALLY_EXPR_BINARY(div)
    TALLY_EXPR_BINARY(pow)
    TALLY_EXPR_BINARY(lt)
    TALLY_EXPR_BINARY(gt)
    TALLY_EXPR_BINARY(le)
    TALLY_EXPR_BINARY(ge)
    TALLY_EXPR_BINARY(eq)
    TALLY_EXPR_BINARY(ne)
    TALLY_EXPR_BINARY(land)
    TALLY_EXPR_BINARY(lor)
    TALLY_EXPR_BINARY(min2)
    TALLY_EXPR_BINARY(max2)
    TALLY_EXPR_BINARY(atan2)
    TALLY_EXPR_UNARY(neg)
    TALLY_EXPR_UNARY(sin)
    TALLY_EXPR_UNARY(cos)
    TALLY_EXPR_UNARY(tan)
    TALLY_EXPR_UNARY(asin)
    TALLY_EXPR_UNARY(acos)
    TALLY_EXPR_UNARY(atan)
    TALLY_EXPR_UNARY(sinh)
    TALLY_EXPR_UNARY(cosh)
    TALLY_EXPR_UNARY(tanh)
    TALLY_EXPR_UNARY(asinh)
    TALLY_EXPR_UNARY(acosh)
    TALLY_EXPR_UNARY(atanh)
    TALLY_EXPR_UNARY(log2)
    TALLY_EXPR_UNARY(log10)
    TALLY_EXPR_UNARY(ln)
    TALLY_EXPR_UNARY(exp)
    TALLY_EXPR_UNARY(sqrt)
    TALLY_EXPR_UNARY(sign)
    TALLY_EXPR_UNARY(rint)
    TALLY_EXPR_UNARY(abs)
#undef TALLY_EXPR_BINARY
#undef TALLY_EXPR_UNARY
    case Op::select:
      select(ins, o, slots, n);
      break;
    case Op::copy:
      if (ins.const_a) {
        std::fill(o, o + n, ins.ka);
      } else {
        std::memcpy(o, slots[ins.a], n * sizeof(double));
      }
      break;
  }
}

struct Scratch {
  std::vector<double> values;
  std::vector<const double*> slots;
};

// run_batch and run_batch_registers: `regs` (num_registers x kBatch) is the caller's, or
// null for the thread's own scratch.
void run(const Program& program, const double* const* xs, size_t n, double* out, double* own_regs) {
  if (n == 0) return;
  thread_local Scratch scratch;
  const size_t padded = (n + kLane - 1) / kLane * kLane;
  const bool partial = padded != n;
  const size_t dims = program.dimensions;
  const size_t extra = partial ? program.used_inputs.size() + 1 : 0;
  const size_t own = own_regs ? 0 : program.num_registers;
  const size_t need = (own + extra) * kBatch;
  if (scratch.values.size() < need) scratch.values.resize(need);
  if (scratch.slots.size() < dims + program.num_registers) {
    scratch.slots.resize(dims + program.num_registers);
  }
  double* regs = own_regs ? own_regs : scratch.values.data();
  const double** slots = scratch.slots.data();
  for (size_t v = 0; v < dims; ++v) slots[v] = xs[v];
  for (size_t r = 0; r < program.num_registers; ++r) slots[dims + r] = regs + r * kBatch;

  double* target = out;
  if (partial) {
    double* pad = scratch.values.data() + own * kBatch;
    for (uint16_t v : program.used_inputs) {
      std::memcpy(pad, xs[v], n * sizeof(double));
      std::fill(pad + n, pad + padded, 0.0);
      slots[v] = pad;
      pad += kBatch;
    }
    target = pad;
  }
  for (const Instr& ins : program.code) {
    double* o = ins.dst == kOutSlot ? target : regs + (ins.dst - dims) * kBatch;
    execute(ins, o, slots, padded);
  }
  if (partial && out) std::memcpy(out, target, n * sizeof(double));
}

}  // namespace

void run_batch(const Program& program, const double* const* xs, size_t n, double* out) {
  run(program, xs, n, out, nullptr);
}

void run_batch_registers(const Program& program, const double* const* xs, size_t n, double* regs) {
  run(program, xs, n, nullptr, regs);
}

double run_point(const Program& program, const double* x) {
  constexpr size_t kStackRegisters = 64;
  double stack_regs[kStackRegisters];
  thread_local std::vector<double> heap_regs;
  double* regs = stack_regs;
  if (program.num_registers > kStackRegisters) {
    if (heap_regs.size() < program.num_registers) heap_regs.resize(program.num_registers);
    regs = heap_regs.data();
  }
  const size_t dims = program.dimensions;
  auto value = [&](uint16_t slot) { return slot < dims ? x[slot] : regs[slot - dims]; };
  double result = 0;
  for (const Instr& ins : program.code) {
    const double a = ins.const_a ? ins.ka : value(ins.a);
    double r;
    if (is_binary(ins.op)) {
      r = apply_binary(ins.op, a, ins.const_b ? ins.kb : value(ins.b));
    } else if (is_unary(ins.op)) {
      r = apply_unary(ins.op, a);
    } else if (ins.op == Op::select) {
      r = value(ins.c) != 0 ? a : (ins.const_b ? ins.kb : value(ins.b));
    } else {
      r = a;  // copy
    }
    if (ins.dst == kOutSlot) {
      result = r;
    } else {
      regs[ins.dst - dims] = r;
    }
  }
  return result;
}

}  // namespace tally::expr
