#pragma once
// The automatic estimator choice (`"estimator": {"type": "auto"}`, issue 31): a short
// pilot of every candidate (plain Monte Carlo, scrambled Sobol', the CBC lattice with
// baker's transform and without) on the job's own integrand, from a stream of its own.
// Each randomized-QMC candidate runs 8 randomizations at 2^10 and 2^13 points; the sd
// of one randomization at the two largest sizes gives its rate (sd ~ points^-rate,
// clamped to [0.5, 1.5]), which predicts the evaluations each needs to reach the target
// half-width at its best point-set size (at least 16 randomizations): 2^10..2^20 Sobol'
// points, 2^10..2^16 lattice points, never more than 2^24 coordinates in one set. When
// the cheapest prediction is at least 4 times what a third size costs, every usable
// candidate also runs 2^16 points (or the sweep bound) and is predicted again from 2^13
// and 2^16: a rate fitted on small sets is often wrong far beyond them. The candidate
// with the fewest predicted evaluations wins. A vector integrand (every component on
// the same points) is predicted per component, against its own target (the stop rule's
// component_targets, else the job-wide one): a point-set size costs what its neediest
// component needs, and that component is named. Cost is counted in evaluations, not
// seconds, so the choice is the same on every machine and every compile of the spec
// (workers, resume).
#include <cstdint>
#include <map>
#include <string>

#include "common/integrate/estimators.hpp"
#include "common/integrate/integration_plan.hpp"
#include "common/integrate/lattice_rule.hpp"

namespace tally {

struct StopRule;

// The lattice rules a pilot built, by point count (each with kDefaultLatticeWeight in every
// dimension): a chosen lattice of a size the pilot ran takes its rule from here instead of
// running the CBC construction again (0.3 s at 2^16 points and d = 32).
using PilotLatticeRules = std::map<uint32_t, LatticeRule>;

// Deterministic in (problem, stop): the targets are the rule's abs_error / rel_error (and a
// vector integrand's component_targets) at its confidence. With `rules`, the lattice rules
// the pilot built are left there.
AutoSelection select_estimator(const IntegrationProblem& problem, const StopRule& stop,
                               PilotLatticeRules* rules = nullptr);

// select_estimator through a memo of its answers in this process. It is a pure function
// of the problem and the stop rule, so `key` must determine both (the integration
// compiler passes the spec's canonical text and the parsed targets): a spec compiled
// again here — validate then submit, a cluster worker's next run of a job, identical
// jobs recovered at start-up — takes the choice, and the chosen lattice's rule, without
// running the pilot again (67 s for 1,000 components, docs/jobs.md). Keeps at most
// kSelectionMemoEntries answers, the least recently used dropped first; thread-safe. Two
// compiles of one key at the same moment each run the pilot (the answers are equal).
inline constexpr size_t kSelectionMemoEntries = 64;
AutoSelection select_estimator_remembered(const std::string& key, const IntegrationProblem& problem,
                                          const StopRule& stop, PilotLatticeRules* rules = nullptr);

// Pilots this process has run (select_estimator calls): for tests of the memo.
uint64_t pilots_run();

}  // namespace tally
