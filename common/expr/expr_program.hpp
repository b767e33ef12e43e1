#pragma once
// The compiled form: a register machine whose every instruction is one tight loop over a
// batch of values in structure-of-arrays layout (slot = one array of kBatch doubles).
// Slots [0, dimensions) are the caller's input arrays, the next num_registers slots are
// scratch registers, kOutSlot is the caller's output. An instruction never writes a slot
// it reads (codegen guarantees it), which lets the kernels use __restrict and vectorize.
#include <cstddef>
#include <cstdint>
#include <vector>

#include "common/expr/expr_ast.hpp"
#include "common/expr/expr_ops.hpp"

namespace tally::expr {

inline constexpr size_t kBatch = 256;
inline constexpr uint16_t kOutSlot = 0xFFFF;

struct Instr {
  Op op = Op::copy;
  uint8_t const_a = 0;  // operand a is the immediate ka instead of slot a
  uint8_t const_b = 0;  // operand b is the immediate kb instead of slot b
  uint16_t dst = 0;
  uint16_t a = 0;
  uint16_t b = 0;
  uint16_t c = 0;  // select: condition slot
  double ka = 0;
  double kb = 0;
};

struct Program {
  size_t dimensions = 0;
  size_t num_registers = 0;
  std::vector<Instr> code;            // the last instruction writes kOutSlot
  std::vector<uint16_t> used_inputs;  // input slots read by the code, ascending
};

// Throws ExprError (limit) beyond max_instructions.
Program generate(const Ast& ast, size_t dimensions, size_t max_instructions);

// out[i] = f(xs[0][i], ..., xs[d-1][i]) for i < n, n <= kBatch. out must not alias an input.
void run_batch(const Program& program, const double* const* xs, size_t n, double* out);

// The same, for a program that writes no output: its registers are left in regs
// (num_registers x kBatch doubles, register r at regs + r * kBatch), each valid on the
// first n values (on a multiple of 8 beyond: values of zero-padded inputs).
void run_batch_registers(const Program& program, const double* const* xs, size_t n, double* regs);

// One point, x[0..d-1], interpreted on scalars (same operations, same results).
double run_point(const Program& program, const double* x);

}  // namespace tally::expr
