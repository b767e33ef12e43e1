#pragma once
// The server's JSON views of a job, built from a JobSnapshot (or, for events the
// manager publishes, from the live runner under its lock): the status document
// (GET /v1/jobs/{id}), the list entry (GET /v1/jobs), and the state/end/progress
// events. Each document has exactly one builder here.
#include <nlohmann/json.hpp>
#include <string>

#include "common/engine/job_definition.hpp"
#include "common/engine/job_runner.hpp"
#include "common/protocol/job_snapshot.hpp"

namespace tally {

// RFC 3339 UTC timestamp with milliseconds, or null for 0.
nlohmann::json time_json(double unix_seconds);
// Bits of channel 0's mean and M2 as hex, for exact comparisons by clients.
nlohmann::json tally_bits_json(const JobState& state);

// Seconds until the job's rule fires (the engine's forecast), or null.
nlohmann::json eta_json(const JobRunner& runner);
// A `progress` event: progress_json + pass + eta_seconds.
nlohmann::json progress_event_json(const JobRunner& runner);
// A `state` event, or with `end` the final `end` event (adds target_met).
nlohmann::json state_event_json(JobStatus status, const JobRunner* runner, const std::string& error, bool end);

// The same for a job whose runner is not in memory (RunFacts, job_snapshot.hpp).
nlohmann::json state_event_json(JobStatus status, const RunFacts* facts, const std::string& error, bool end);

// What the views need of a runner once its state is released (or before it exists).
// `progress_event`: its data already built (progress_event_json, dumped), else built here.
RunFacts run_facts(const JobRunner& runner, const std::string* progress_event = nullptr);
// run_facts without the progress event (and target_met): what the status and list
// documents of a running job show, built at its pass boundary (JobManager::snapshot).
RunFacts live_run_facts(const JobRunner& runner);
RunFacts fresh_run_facts(const StopRule& rule);  // a job that has not started
// Stored beside a finished job (the store's `facts` column), without the rule (stored
// on its own). parse_run_facts throws std::exception on a malformed document.
nlohmann::json run_facts_json(const RunFacts& facts);
RunFacts parse_run_facts(const nlohmann::json& j, const StopRule& rule);

// The engine part of a job's status: result_json + summary, eta_seconds, bits.
nlohmann::json engine_json(const JobDefinition& def, const JobRunner& runner);
// GET /v1/jobs/{id}. `links`: the job's URLs (the API layer builds them).
nlohmann::json status_json(const JobSnapshot& job, double now, nlohmann::json links);
// The short form GET /v1/jobs lists (and DELETE/extend answer with).
nlohmann::json summary_json(const JobSnapshot& job);

}  // namespace tally
