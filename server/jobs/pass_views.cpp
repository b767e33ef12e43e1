#include "server/jobs/pass_views.hpp"

#include <algorithm>
#include <climits>
#include <set>

#include "common/protocol/job_json.hpp"
#include "common/protocol/job_kinds.hpp"

namespace tally {

using nlohmann::json;

namespace {

std::string dump(const json& j) { return j.dump(-1, ' ', false, json::error_handler_t::replace); }

// The pass's tile events of an image job: one `tile` event per tile refined in the
// pass, or, above kMaxTileEventsPerPass tiles (a pass over a 4K frame refines 8,160),
// one `tiles` event for all of them: their count, first and last index and the pixel
// rectangle that bounds them. A watcher's bytes per pass stay bounded and a pass never
// overruns the replay buffer (which would turn every watcher's next read into a snapshot).
std::vector<TileEvent> tile_events(const ImageSource* img, const std::vector<Block>& blocks, uint64_t pass) {
  std::vector<TileEvent> out;
  if (!img) return out;
  std::set<uint32_t> tiles;
  for (const Block& b : blocks) tiles.insert(img->tile_of_partition(b.partition));
  if (tiles.size() > kMaxTileEventsPerPass) {
    int x0 = INT_MAX, y0 = INT_MAX, x1 = 0, y1 = 0;
    for (uint32_t t : tiles) {
      const TileRect rc = img->tile_rect(t);
      x0 = std::min(x0, rc.x);
      y0 = std::min(y0, rc.y);
      x1 = std::max(x1, rc.x + rc.w);
      y1 = std::max(y1, rc.y + rc.h);
    }
    out.push_back({"tiles", dump(json{{"count", tiles.size()}, {"first", *tiles.begin()}, {"last", *tiles.rbegin()},
                                      {"x", x0}, {"y", y0}, {"w", x1 - x0}, {"h", y1 - y0}, {"pass", pass}})});
    return out;
  }
  for (uint32_t t : tiles) {
    const TileRect rc = img->tile_rect(t);
    out.push_back({"tile", dump(json{{"tile", t}, {"x", rc.x}, {"y", rc.y}, {"w", rc.w}, {"h", rc.h}, {"pass", pass}})});
  }
  return out;
}

}  // namespace

std::shared_ptr<const std::string> progress_data(const JobDefinition* def, const JobRunner& r) {
  json j = progress_event_json(r);
  if (def) j.update(kind_progress_json(*def, r));  // e.g. a vector integrand's components
  return std::make_shared<const std::string>(dump(j));
}

PassViews pass_events(const JobDefinition* def, const JobRunner& r, const std::vector<Block>& blocks) {
  PassViews v;
  v.progress = progress_data(def, r);
  v.tiles = tile_events(def ? def->image() : nullptr, blocks, r.state().passes);
  return v;
}

PassViews running_views(const JobDefinition* def, const JobRunner& r, const std::vector<Block>& blocks) {
  PassViews v = pass_events(def, r, blocks);
  v.engine = def ? std::make_shared<const json>(engine_json(*def, r)) : nullptr;
  v.live = std::make_shared<const RunFacts>(live_run_facts(r));
  return v;
}

FinishViews finish_views(const JobDefinition* def, const JobRunner& r, std::shared_ptr<const std::string> progress) {
  FinishViews v;
  v.progress = std::move(progress);
  v.final_result = std::make_shared<const json>(def ? engine_json(*def, r) : json::object());
  v.facts = std::make_shared<const RunFacts>(run_facts(r, v.progress.get()));
  return v;
}

PassWork plan_next(JobRunner& r) {
  PassWork w;
  w.pass = r.state().passes;
  w.blocks = r.plan_pass();
  w.groups = r.result_groups();
  w.pass_input = r.pass_input();
  if (w.empty()) return w;
  bool ahead_followed = false;
  if (auto blocks = r.plan_ahead(&ahead_followed)) {
    auto ahead = std::make_shared<PassWork>();
    ahead->pass = w.pass + 1;
    ahead->followed = ahead_followed;
    w.followed = true;
    ahead->blocks = std::move(*blocks);
    ahead->groups = result_groups(ahead->blocks, r.kernel().schedule().group_blocks);
    w.ahead = std::move(ahead);
  }
  return w;
}

}  // namespace tally
