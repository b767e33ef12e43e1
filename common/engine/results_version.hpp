#pragma once
// The results version: which generation of the engine's arithmetic computed a job's
// state. Two builds with the same version give the same bits for the same spec and seed;
// a change that alters those bits (a sampler, a kernel, a default such as the glTF BRDF,
// the order of a reduction) must bump it. The golden test refuses to rewrite changed
// bits under an unchanged version (tests/golden, TALLY_UPDATE_GOLDEN).
//
// It travels with the state (JobState::results_version, stored in checkpoints) and the
// facts of a finished job (RunFacts::results_version), and the server's result cache
// answers a submit only from a job of the current version: after an upgrade that
// changed results, older finished jobs are still readable but answer no new submit.
// Version 0 means "unknown": state written before the version was recorded.
//
// History: 1, the first recorded; 2, the automatic estimator's choice (Sobol' sets to
// 2^20 points, a third pilot size for large jobs) changed what an "auto" spec computes;
// 3, an image with replicates keeps a sum per replicate channel (a replicate's mean is
// its sum over its count, not a running mean; a non-finite sample counts as 0); 4, those
// sums are kept in single precision, rounded once per merged result group; 5, an image
// job's default replicates went from 8 to 4 (a sobol image spec without "replicates").
#include <cstdint>

namespace tally {

inline constexpr uint32_t kResultsVersion = 5;

}  // namespace tally
