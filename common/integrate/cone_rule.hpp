#pragma once
// The cone-based stop rule for digital nets of Hickernell & Jiménez Rugama ("Reliable
// adaptive cubature using digital sequences", 2016; GAIL's cubSobol_g): one scrambled
// Sobol' sequence, its points doubled from 2^m_min until an error bound computed from the
// integrand's discrete Walsh coefficients meets the target.
//
// With n = 2^m points of a digital net in natural order, the normalised fast Walsh-Hadamard
// transform of the values gives n discrete Walsh coefficients (coefficient 0 is the
// estimate, the mean). They are put in an order close to decreasing size (`kappa`, built
// from the data as cubSobol_g does: at each level the larger of a pair of coefficients
// takes the lower wavenumber). For integrands whose true Walsh coefficients decay in the
// way the cone assumes, |I - estimate| <= fudge * 2^-m * S, S the sum of the magnitudes of
// the coefficients at the kappa positions [2^(m-lag-1), 2^(m-lag)). That is a
// deterministic bound for functions in the cone, not a confidence interval: what it
// promises depends on the integrand being in the cone, which cannot be checked.
// cubSobol_g also tests necessary conditions of the cone (band sums consistent across
// m); they are not here: at its constants they failed on all 69 runs of the hard-regime
// study, where the bound covered 65 (docs/jobs.md), so they told nothing.
//
// The same rule for embedded rank-1 lattices (Jiménez Rugama & Hickernell 2016; GAIL's
// cubLattice_g): the coefficients are the normalised discrete Fourier transform of the
// lattice's values (their magnitudes ordered and summed as above), the points taken in
// radical-inverse order so that every doubling adds the odd multiples of the finer
// lattice; the lattice is built by the embedded fast CBC (lattice_rule.hpp).
//
// The algorithm here is pure (no integrand, no engine): it asks a callback for the values
// at positions [first, first + n) (natural indices of the net; radical-inverse positions
// of the lattice) and owns the coefficient arrays. Not thread-safe; one instance per run.
// Memory: 12 bytes a point for nets (a double coefficient, a 32-bit index), 20 for
// lattices (complex coefficients).
#include <complex>
#include <cstdint>
#include <functional>
#include <memory>
#include <span>

#include "common/engine/kernel.hpp"
#include "common/integrate/estimators.hpp"
#include "common/integrate/lattice_rule.hpp"

namespace tally {

// One block's points at most (12 bytes each while the rule runs: 192 MiB).
inline constexpr uint64_t kMaxConeEvaluations = uint64_t{1} << 24;
// The lattice's: its embedded CBC is built for 2^20 points (1 to 4 s of CPU at d = 8 to
// 32, once per process and weights; 20 bytes a point while the rule runs: 20 MiB).
inline constexpr uint32_t kLatticeConeLog2 = 20;
inline constexpr uint32_t kMaxLatticeConeDimensions = 32;

// The coefficients of the bound: Walsh (digital nets) or Fourier (lattices).
enum class ConeBasis { walsh, fourier };

struct ConeRuleOptions {
  uint32_t m_min = 10;   // first 2^m_min points (cubSobol_g's mmin)
  uint32_t m_max = 20;   // at most 2^m_max points (a budget, not a target)
  uint32_t lag = 4;      // r: the coefficients summed are 2^lag below the ones computed
  double fudge = 5.0;    // the bound is fudge * 2^-m * S (cubSobol_g's default fudge(m) = 5 * 2^-m)
  ConeBasis basis = ConeBasis::walsh;
  // Targets, either: met when bound <= max(abs_error, rel_error * (|mean| - bound)), the
  // relative one against the smallest |I| the bound allows (cubSobol_g instead shifts the
  // estimate within the bound); both 0: runs to 2^m_max.
  double abs_error = 0;
  double rel_error = 0;
};

struct ConeRuleResult {
  double mean = 0.0;         // the estimate: the mean of the 2^m values
  double error_bound = 0.0;  // fudge * 2^-m * S at the last m
  uint32_t m = 0;            // 2^m points used
  bool met = false;          // the bound met the target
  bool aborted = false;      // the callback returned false (a fault, or the run was abandoned)
};

// values(first, n, out): writes the integrand's values at natural indices [first, first + n)
// of the net (n a power of two, first = 0 or n); returns false to stop the rule.
using ConeValues = std::function<bool(uint64_t first, uint64_t n, double* out)>;

// Runs the rule. Options must satisfy lag + 1 <= m_min <= m_max <= 30.
ConeRuleResult run_cone_rule(const ConeRuleOptions& o, const ConeValues& values);

// The normalised fast Walsh-Hadamard transform in place (size a power of two):
// y_k = 2^-m sum_i (-1)^{popcount(i & k)} x_i. Exposed for the tests.
void walsh_hadamard_normalized(std::span<double> y);

// The normalised DFT of values given in radical-inverse order of their natural index
// (position p holds natural index bitreverse_m(p)): y_k = 2^-m sum_j x_j e^{-2 pi i j k / n}
// in natural order k. One level joins halves of span h; exposed for the tests.
void lattice_dft_normalized(std::span<std::complex<double>> y);
void lattice_dft_level(std::span<std::complex<double>> y, size_t h);

// The rule as an integration job's kernel (`"estimator": {"type": "qmc", "error": "cone"}`):
// the whole rule runs in one block of one pass on one randomization of the Sobol' sequence
// (the qmc estimator's affine scramble, seeded by the job's seed), like cubature: deterministic, the same
// bits for any thread or worker count, cancel polled between batches. Channels: 0 the
// mean, 1 the error bound. Scalar integrands only.
std::shared_ptr<const Kernel> make_cone_kernel(IntegrationProblem p, ConeRuleOptions o);

// The lattice form (`"estimator": {"type": "lattice", "error": "cone"}`): the points
// {phi_2(p) z + shift}, p in radical-inverse order, through the periodizing transform;
// the shift is the lattice estimator's first (seeded by the job's seed). The same
// channels; o.basis must be fourier and o.m_max <= rule.m_max.
std::shared_ptr<const Kernel> make_lattice_cone_kernel(IntegrationProblem p, EmbeddedLatticeRule rule,
                                                       Periodization per, ConeRuleOptions o);

}  // namespace tally
