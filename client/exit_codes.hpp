#pragma once
// Exit codes of the `tally` CLI, shared by every command (documented in docs/api.md,
// "The `tally` CLI").
namespace tally::exit_code {
inline constexpr int ok = 0;              // the job finished and met its target (if any)
inline constexpr int target_not_met = 2;  // finished by samples/time before the error target
inline constexpr int job_failed = 3;      // failed or cancelled
inline constexpr int usage = 4;           // bad arguments, an unreadable or invalid job spec, 4xx about the request
inline constexpr int connection = 5;      // could not reach the server, 5xx, or an unexpected answer
inline constexpr int auth = 6;            // 401 (no or wrong token) or 403 (the token may not do this)
}  // namespace tally::exit_code
