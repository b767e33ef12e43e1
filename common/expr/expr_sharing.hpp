#pragma once
// Several programs over the same inputs, run together with what they have in common run
// once. An instruction's value is numbered by its operation, its immediates and its
// operands' numbers (the inputs are numbers 0..d-1), across all the programs; a value two
// or more programs compute is *shared*: the prelude computes every shared value once a
// batch, each into a register of its own, and each program's residual — the program
// without its shared instructions — reads them as extra inputs after the d real ones.
// The operands of a shared value are shared too (every program that computes it computes
// them), so the prelude is closed. Each residual keeps its program's register numbers,
// shifted past the shared inputs: dropping instructions only removes writes, so every
// value a residual reads is the one its program read. Every result is therefore the same
// operations on the same values in the same order as the program's own run_batch:
// bit-identical (tests/expr/expr_sharing_test.cpp).
//
// Typical case: one template at many parameter values, exp(s*(sin(2*_pi*x0)+...)) at
// 1,000 values of s — the sines and their sum are shared, each residual is a product and
// an exp (docs/jobs.md, vector integrands).
#include <cstddef>
#include <memory>
#include <vector>

#include "common/expr/expr_program.hpp"

namespace tally::expr {

struct SharedPrograms {
  size_t dimensions = 0;
  Program prelude;                // dimensions d; register k holds shared value k
  std::vector<Program> residual;  // dimensions d + shared; one per program, in order
  // Nothing shared (no value in common, or past the limits below): the programs
  // themselves, run one by one (residual empty).
  std::vector<std::shared_ptr<const Program>> alone;
  size_t shared() const { return prelude.num_registers; }
  size_t size() const { return alone.empty() ? residual.size() : alone.size(); }
};

// Limits: the numbering's table (all the programs' instructions, about 80 bytes each while
// it is built), slot numbers within uint16 and the prelude's registers (kBatch doubles
// each) within 8 MiB a thread. Past them the programs run alone.
inline constexpr size_t kMaxSharingInstructions = size_t{1} << 20;
inline constexpr size_t kMaxSharedValues = 4096;

// `programs` all have the same dimensions.
SharedPrograms share_programs(const std::vector<std::shared_ptr<const Program>>& programs);

// out[k][i] = program first + k at point i, for k < count and i < n (any n): the prelude
// once a batch, then those residuals. Thread-safe (thread_local scratch).
void run_shared(const SharedPrograms& sp, size_t first, size_t count, const double* const* xs, size_t n,
                double* const* out);

}  // namespace tally::expr
