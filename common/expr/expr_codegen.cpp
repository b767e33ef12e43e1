// AST -> register program. Operands are constants (folded into immediates), input slots
// or registers; a register is freed as soon as its value has been consumed, and the
// destination is allocated before the sources are freed so it never aliases them.
#include <algorithm>
#include <string>

#include "common/expr/expr_error.hpp"
#include "common/expr/expr_program.hpp"

namespace tally::expr {
namespace {

struct Operand {
  bool is_constant = false;
  double value = 0;
  uint16_t slot = 0;
};

class CodeGen {
 public:
  CodeGen(const Ast& ast, size_t dimensions, size_t max_instructions)
      : ast_(ast), max_instructions_(max_instructions) {
    program_.dimensions = dimensions;
  }

  Program run() {
    Operand r = gen(ast_.root);
    if (!r.is_constant && r.slot >= program_.dimensions && !program_.code.empty() &&
        program_.code.back().dst == r.slot) {
      program_.code.back().dst = kOutSlot;  // the last result goes straight to the output
    } else {
      Instr copy;
      copy.op = Op::copy;
      copy.const_a = r.is_constant;
      copy.ka = r.value;
      copy.a = r.slot;
      copy.dst = kOutSlot;
      push(copy);
    }
    std::sort(program_.used_inputs.begin(), program_.used_inputs.end());
    program_.used_inputs.erase(
        std::unique(program_.used_inputs.begin(), program_.used_inputs.end()),
        program_.used_inputs.end());
    return std::move(program_);
  }

 private:
  uint16_t allocate() {
    if (!free_.empty()) {
      uint16_t r = free_.back();
      free_.pop_back();
      return r;
    }
    const size_t slot = program_.dimensions + program_.num_registers;
    if (slot >= kOutSlot) too_many();
    ++program_.num_registers;
    return static_cast<uint16_t>(slot);
  }
  void release(const Operand& o) {
    if (!o.is_constant && o.slot >= program_.dimensions) free_.push_back(o.slot);
  }
  [[noreturn]] void too_many() const {
    throw ExprError(ExprErrorKind::limit, "expression compiles to more than " +
                                              std::to_string(max_instructions_) +
                                              " instructions; simplify it");
  }
  void push(const Instr& ins) {
    if (program_.code.size() >= max_instructions_) too_many();
    program_.code.push_back(ins);
  }
  static void set_a(Instr& ins, const Operand& o) {
    ins.const_a = o.is_constant;
    ins.ka = o.value;
    ins.a = o.slot;
  }
  static void set_b(Instr& ins, const Operand& o) {
    ins.const_b = o.is_constant;
    ins.kb = o.value;
    ins.b = o.slot;
  }

  Operand emit_unary(Op op, Operand a) {
    if (a.is_constant) return {true, apply_unary(op, a.value), 0};
    Instr ins;
    ins.op = op;
    set_a(ins, a);
    ins.dst = allocate();
    release(a);
    push(ins);
    return {false, 0, ins.dst};
  }

  // keep_a: a is read again later (x^3 = (x*x)*x), do not free it yet.
  Operand emit_binary(Op op, Operand a, Operand b, bool keep_a = false) {
    if (a.is_constant && b.is_constant) return {true, apply_binary(op, a.value, b.value), 0};
    Instr ins;
    ins.op = op;
    set_a(ins, a);
    set_b(ins, b);
    ins.dst = allocate();
    if (!keep_a) release(a);
    if (b.is_constant || a.is_constant || b.slot != a.slot) release(b);
    push(ins);
    return {false, 0, ins.dst};
  }

  // x^2, x^3, x^4 as products, as muParser's optimizer does; std::pow is within half an
  // ulp of them, far inside the cross-check tolerance.
  Operand emit_power(Operand base, Operand exponent) {
    if (!base.is_constant && exponent.is_constant) {
      if (exponent.value == 1) return base;
      if (exponent.value == 2) return emit_binary(Op::mul, base, base);
      if (exponent.value == 3) {
        Operand sq = emit_binary(Op::mul, base, base, /*keep_a=*/true);
        return emit_binary(Op::mul, sq, base);
      }
      if (exponent.value == 4) {
        Operand sq = emit_binary(Op::mul, base, base);
        return emit_binary(Op::mul, sq, sq);
      }
    }
    return emit_binary(Op::pow, base, exponent);
  }

  Operand gen(NodeId id) {
    const Node& n = ast_[id];
    switch (n.kind) {
      case NodeKind::constant:
        return {true, n.value, 0};
      case NodeKind::variable:
        program_.used_inputs.push_back(static_cast<uint16_t>(n.var));
        return {false, 0, static_cast<uint16_t>(n.var)};
      case NodeKind::unary:
        return emit_unary(n.op, gen(n.kids[0]));
      case NodeKind::binary: {
        Operand a = gen(n.kids[0]);
        Operand b = gen(n.kids[1]);
        if (n.op == Op::pow) return emit_power(a, b);
        return emit_binary(n.op, a, b);
      }
      case NodeKind::chain: {
        Operand acc = gen(n.kids[0]);
        for (size_t i = 1; i < n.kids.size(); ++i)
          acc = emit_binary(n.ops[i - 1], acc, gen(n.kids[i]));
        return acc;
      }
      case NodeKind::select: {
        Operand c = gen(n.kids[0]);
        if (c.is_constant) return gen(n.kids[select_value(c.value, 1, 2) == 1 ? 1 : 2]);
        Operand a = gen(n.kids[1]);
        Operand b = gen(n.kids[2]);
        Instr ins;
        ins.op = Op::select;
        ins.c = c.slot;
        set_a(ins, a);
        set_b(ins, b);
        ins.dst = allocate();
        release(c);
        release(a);
        release(b);
        push(ins);
        return {false, 0, ins.dst};
      }
    }
    return {true, 0, 0};
  }

  const Ast& ast_;
  size_t max_instructions_;
  Program program_;
  std::vector<uint16_t> free_;
};

}  // namespace

Program generate(const Ast& ast, size_t dimensions, size_t max_instructions) {
  return CodeGen(ast, dimensions, max_instructions).run();
}

}  // namespace tally::expr
