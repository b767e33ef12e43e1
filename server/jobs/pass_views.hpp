#pragma once
// What a pass boundary publishes, built from the job's runner without the job's lock
// (each part can be a pass over every pixel of an image): the progress event, the tile
// events, and the status views (running) or the final ones (finished). Also the
// runner's next pass as an executor takes it.
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "common/engine/job_definition.hpp"
#include "common/engine/job_runner.hpp"
#include "common/protocol/job_snapshot.hpp"
#include "server/executor/executor.hpp"
#include "server/jobs/job.hpp"

namespace tally {

// Above this many tiles refined in a pass, the pass publishes one `tiles` event
// (count, first, last, bounding rectangle) instead of a `tile` event per tile.
inline constexpr size_t kMaxTileEventsPerPass = 64;

struct TileEvent {
  std::string type;  // "tile" or "tiles"
  std::string data;
};

struct PassViews {
  std::shared_ptr<const std::string> progress;  // the progress event's data
  std::vector<TileEvent> tiles;                 // the pass's tile events (tile_events in pass_views.cpp)
  std::shared_ptr<const nlohmann::json> engine; // a running job's status (engine_json); null for no definition
  std::shared_ptr<const RunFacts> live;         // live_run_facts
};

// The views of a pass that did not end the job. `blocks`: the pass's blocks (tiles).
PassViews running_views(const JobDefinition* def, const JobRunner& r, const std::vector<Block>& blocks);
// The views of the pass that ended it (its progress event, tile events, final result, facts).
PassViews pass_events(const JobDefinition* def, const JobRunner& r, const std::vector<Block>& blocks);
FinishViews finish_views(const JobDefinition* def, const JobRunner& r, std::shared_ptr<const std::string> progress);
// The progress event's data for the runner as it is now, with what the job's kind adds
// (kind_progress_json) when `def` is given.
std::shared_ptr<const std::string> progress_data(const JobDefinition* def, const JobRunner& r);

// The runner's next pass for an executor, with the one after it when that can be
// planned already (JobRunner::plan_ahead). Empty when the job is finished.
PassWork plan_next(JobRunner& r);

}  // namespace tally
