#pragma once
// Exit codes of the `tally` CLI, shared by every command (documented in docs/cli.md).
namespace tally::exit_code {
inline constexpr int ok = 0;              // the job finished and met its target (if any)
inline constexpr int target_not_met = 2;  // finished by samples/time before the error target
inline constexpr int job_failed = 3;      // failed or cancelled
inline constexpr int usage = 4;           // bad arguments or an invalid job spec
inline constexpr int connection = 5;      // could not reach the server / unexpected HTTP status
}  // namespace tally::exit_code
