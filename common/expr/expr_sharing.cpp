#include "common/expr/expr_sharing.hpp"

#include <algorithm>
#include <bit>
#include <cstdint>
#include <utility>

namespace tally::expr {

namespace {

constexpr uint32_t kNone = 0xFFFFFFFFu;
constexpr size_t kMaxInputs = 64;  // CompiledExpression::kMaxDimensions

// What an instruction computes, in value numbers: equal keys, equal values.
struct Key {
  Op op = Op::copy;
  uint8_t const_a = 0, const_b = 0;
  uint64_t a = 0, b = 0;  // an operand's value number, or an immediate's bits
  uint32_t c = kNone;     // select: the condition's value number
  bool operator==(const Key&) const = default;
  uint64_t hash() const {
    uint64_t h = (static_cast<uint64_t>(op) << 16) ^ (static_cast<uint64_t>(const_a) << 8) ^ const_b;
    for (uint64_t v : {a, b, static_cast<uint64_t>(c)}) {
      h ^= v + 0x9e3779b97f4a7c15ULL + (h << 6) + (h >> 2);
      h *= 0xff51afd7ed558ccdULL;
    }
    return h ^ (h >> 33);
  }
};

// Value numbers by key: an open-addressing table of indices into `keys` (4 bytes a slot,
// at most half full), so the numbering of 10,000 components costs little beside them.
class Numbering {
 public:
  // The number of `k` (first: d + its index in keys()), and whether it is new.
  std::pair<uint32_t, bool> number(const Key& k, uint32_t d) {
    if (2 * (keys_.size() + 1) > table_.size()) grow();
    const size_t mask = table_.size() - 1;
    for (size_t i = k.hash() & mask;; i = (i + 1) & mask) {
      const uint32_t e = table_[i];
      if (e == kNone) {
        table_[i] = static_cast<uint32_t>(keys_.size());
        keys_.push_back(k);
        return {static_cast<uint32_t>(d + keys_.size() - 1), true};
      }
      if (keys_[e] == k) return {d + e, false};
    }
  }
  const std::vector<Key>& keys() const { return keys_; }

 private:
  void grow() {
    std::vector<uint32_t> t(std::max<size_t>(64, 2 * table_.size()), kNone);
    const size_t mask = t.size() - 1;
    for (uint32_t e = 0; e < keys_.size(); ++e) {
      size_t i = keys_[e].hash() & mask;
      while (t[i] != kNone) i = (i + 1) & mask;
      t[i] = e;
    }
    table_ = std::move(t);
  }
  std::vector<uint32_t> table_;
  std::vector<Key> keys_;
};

bool reads_b(Op op) { return is_binary(op) || op == Op::select; }

// An instruction's operand slots and the value numbers in them.
struct Numbered {
  uint32_t vn = kNone;
  uint32_t a = kNone, b = kNone, c = kNone;  // operand value numbers (kNone: immediate or unused)
};

}  // namespace

SharedPrograms share_programs(const std::vector<std::shared_ptr<const Program>>& programs) {
  SharedPrograms sp;
  if (programs.empty()) return sp;
  const size_t d = programs.front()->dimensions;
  sp.dimensions = d;
  size_t total = 0;
  for (const auto& p : programs) total += p->code.size();
  if (programs.size() < 2 || total > kMaxSharingInstructions) {
    sp.alone = programs;
    return sp;
  }
  Numbering numbering;
  std::vector<uint32_t> programs_using;     // by value number - d
  std::vector<uint32_t> last_program;       // by value number - d
  std::vector<std::vector<Numbered>> numbered(programs.size());
  for (size_t p = 0; p < programs.size(); ++p) {
    const Program& prog = *programs[p];
    std::vector<uint32_t> slot(d + prog.num_registers, kNone);
    for (uint32_t v = 0; v < d; ++v) slot[v] = v;
    numbered[p].reserve(prog.code.size());
    for (const Instr& ins : prog.code) {
      Numbered nb;
      Key k;
      // An operand's part of the key: the immediate's bits, or the number in its slot.
      const auto operand = [&](bool immediate, double value, uint16_t slot_no, uint32_t& number) -> uint64_t {
        if (immediate) return std::bit_cast<uint64_t>(value);
        number = slot[slot_no];
        return number;
      };
      k.op = ins.op;
      k.const_a = ins.const_a;
      k.a = operand(ins.const_a != 0, ins.ka, ins.a, nb.a);
      if (reads_b(ins.op)) {
        k.const_b = ins.const_b;
        k.b = operand(ins.const_b != 0, ins.kb, ins.b, nb.b);
      }
      if (ins.op == Op::select) {
        nb.c = slot[ins.c];
        k.c = nb.c;
      }
      const auto [vn, fresh] = numbering.number(k, static_cast<uint32_t>(d));
      if (fresh) {
        programs_using.push_back(0);
        last_program.push_back(kNone);
      }
      nb.vn = vn;
      const size_t i = nb.vn - d;
      if (last_program[i] != p) {
        last_program[i] = static_cast<uint32_t>(p);
        programs_using[i] += 1;
      }
      if (ins.dst != kOutSlot) slot[ins.dst] = nb.vn;
      numbered[p].push_back(nb);
    }
  }

  const std::vector<Key>& keys = numbering.keys();  // by value number - d
  // Shared values, in value-number order (operands are numbered before their users).
  std::vector<uint32_t> shared_index(keys.size(), kNone);
  size_t shared = 0;
  for (size_t i = 0; i < keys.size(); ++i) {
    if (programs_using[i] >= 2) shared_index[i] = static_cast<uint32_t>(shared++);
  }
  size_t max_registers = 0;
  for (const auto& p : programs) max_registers = std::max(max_registers, p->num_registers);
  if (shared == 0 || shared > kMaxSharedValues || d + shared + max_registers >= kOutSlot) {
    sp.alone = programs;
    return sp;
  }
  const auto shared_slot = [&](uint32_t vn) -> uint32_t {
    if (vn == kNone || vn < d) return kNone;
    const uint32_t k = shared_index[vn - d];
    return k == kNone ? kNone : static_cast<uint32_t>(d + k);
  };

  // The prelude: each shared value once, into its own register.
  sp.prelude.dimensions = d;
  sp.prelude.num_registers = shared;
  for (size_t i = 0; i < keys.size(); ++i) {
    if (shared_index[i] == kNone) continue;
    const Key& k = keys[i];
    Instr ins;
    ins.op = k.op;
    ins.dst = static_cast<uint16_t>(d + shared_index[i]);
    const auto operand = [&](uint64_t vn) {
      const auto v = static_cast<uint32_t>(vn);
      return static_cast<uint16_t>(v < d ? v : shared_slot(v));
    };
    ins.const_a = k.const_a;
    if (k.const_a) {
      ins.ka = std::bit_cast<double>(k.a);
    } else {
      ins.a = operand(k.a);
    }
    if (reads_b(k.op)) {
      ins.const_b = k.const_b;
      if (k.const_b) {
        ins.kb = std::bit_cast<double>(k.b);
      } else {
        ins.b = operand(k.b);
      }
    }
    if (k.op == Op::select) ins.c = operand(k.c);
    sp.prelude.code.push_back(ins);
  }

  // Each residual: its program without the shared instructions, reading shared values
  // as inputs d..d+shared-1 and its own registers shifted past them.
  for (size_t p = 0; p < programs.size(); ++p) {
    const Program& prog = *programs[p];
    Program r;
    r.dimensions = d + shared;
    r.num_registers = prog.num_registers;
    const auto remap = [&](uint16_t slot_no, uint32_t vn) -> uint16_t {
      if (const uint32_t s = shared_slot(vn); s != kNone) return static_cast<uint16_t>(s);
      return slot_no < d ? slot_no : static_cast<uint16_t>(slot_no + shared);
    };
    for (size_t j = 0; j < prog.code.size(); ++j) {
      const Instr& in = prog.code[j];
      const Numbered& nb = numbered[p][j];
      if (const uint32_t s = shared_slot(nb.vn); s != kNone) {
        if (in.dst == kOutSlot) {  // the result itself is shared: copy it out
          Instr cp;
          cp.op = Op::copy;
          cp.dst = kOutSlot;
          cp.a = static_cast<uint16_t>(s);
          r.code.push_back(cp);
        }
        continue;
      }
      Instr out = in;
      if (!in.const_a) out.a = remap(in.a, nb.a);
      if (reads_b(in.op) && !in.const_b) out.b = remap(in.b, nb.b);
      if (in.op == Op::select) out.c = remap(in.c, nb.c);
      if (in.dst != kOutSlot) out.dst = static_cast<uint16_t>(in.dst + shared);
      r.code.push_back(out);
    }
    std::vector<uint16_t> used;
    for (const Instr& ins : r.code) {
      if (!ins.const_a && ins.a < r.dimensions) used.push_back(ins.a);
      if (reads_b(ins.op) && !ins.const_b && ins.b < r.dimensions) used.push_back(ins.b);
      if (ins.op == Op::select && ins.c < r.dimensions) used.push_back(ins.c);
    }
    std::sort(used.begin(), used.end());
    used.erase(std::unique(used.begin(), used.end()), used.end());
    r.used_inputs = std::move(used);
    sp.residual.push_back(std::move(r));
  }
  std::vector<uint16_t> used;
  for (const Instr& ins : sp.prelude.code) {
    if (!ins.const_a && ins.a < d) used.push_back(ins.a);
    if (reads_b(ins.op) && !ins.const_b && ins.b < d) used.push_back(ins.b);
    if (ins.op == Op::select && ins.c < d) used.push_back(ins.c);
  }
  std::sort(used.begin(), used.end());
  used.erase(std::unique(used.begin(), used.end()), used.end());
  sp.prelude.used_inputs = std::move(used);
  return sp;
}

void run_shared(const SharedPrograms& sp, size_t first, size_t count, const double* const* xs, size_t n,
                double* const* out) {
  if (!sp.alone.empty()) {
    const double* shifted[kMaxInputs];
    for (size_t start = 0; start < n; start += kBatch) {
      const size_t m = std::min(kBatch, n - start);
      for (size_t v = 0; v < sp.dimensions; ++v) shifted[v] = xs[v] + start;
      for (size_t k = 0; k < count; ++k) run_batch(*sp.alone[first + k], shifted, m, out[k] + start);
    }
    return;
  }
  const size_t d = sp.dimensions, shared = sp.shared();
  thread_local std::vector<double> values;
  thread_local std::vector<const double*> inputs;
  if (values.size() < shared * kBatch) values.resize(shared * kBatch);
  inputs.resize(d + shared);
  for (size_t k = 0; k < shared; ++k) inputs[d + k] = values.data() + k * kBatch;
  for (size_t start = 0; start < n; start += kBatch) {
    const size_t m = std::min(kBatch, n - start);
    for (size_t v = 0; v < d; ++v) inputs[v] = xs[v] + start;
    run_batch_registers(sp.prelude, inputs.data(), m, values.data());
    for (size_t k = 0; k < count; ++k) run_batch(sp.residual[first + k], inputs.data(), m, out[k] + start);
  }
}

}  // namespace tally::expr
