#include "server/jobs/pass_views.hpp"

#include <set>

#include "common/protocol/job_json.hpp"
#include "common/protocol/job_kinds.hpp"

namespace tally {

using nlohmann::json;

namespace {

std::string dump(const json& j) { return j.dump(-1, ' ', false, json::error_handler_t::replace); }

// The pass's tile events of an image job (one per tile refined in the pass).
std::vector<std::string> tile_events(const ImageSource* img, const std::vector<Block>& blocks, uint64_t pass) {
  std::vector<std::string> out;
  if (!img) return out;
  std::set<uint32_t> tiles;
  for (const Block& b : blocks) tiles.insert(img->tile_of_partition(b.partition));
  for (uint32_t t : tiles) {
    const TileRect rc = img->tile_rect(t);
    out.push_back(dump(json{{"tile", t}, {"x", rc.x}, {"y", rc.y}, {"w", rc.w}, {"h", rc.h}, {"pass", pass}}));
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
