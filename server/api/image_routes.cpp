// The image routes: GET /v1/jobs/{id}/tiles/{n}, image.exr, image.png. They read
// the immutable state of a JobSnapshot (a finished job's is read back from the
// store, JobManager::state), so encoding never holds a job's lock.
#include <fmt/format.h>

#include "common/protocol/job_json.hpp"
#include "server/api/request_handler.hpp"
#include "server/api/route_support.hpp"

namespace tally {

using nlohmann::json;

namespace {

const ImageSource& image_of(const JobSnapshot& s) {
  const ImageSource* img = s.def ? s.def->image() : nullptr;
  if (!img) throw HttpError(404, fmt::format("job {} has no image", s.id));
  return *img;
}

}  // namespace

HttpResponse RequestHandler::job_tile(const ApiRequest& req, const PathParams& p) {
  const JobSnapshot s = visible_snapshot(req, p.at("id"), JobManager::SnapshotOf::state);
  const auto n = parse_u64(p.at("n"));
  const ImageSource& img = image_of(s);
  if (!n || *n >= img.tile_count()) {
    throw HttpError(404, fmt::format("tile \"{}\" does not exist; the image has {} tiles", p.at("n"), img.tile_count()));
  }
  const std::shared_ptr<const JobState> state = manager_.state(s);  // a finished job's: from the store
  if (!state) throw HttpError(409, "the job's state is not available");
  const TileRect rc = img.tile_rect(static_cast<uint32_t>(*n));
  const ImageSnapshot t = img.snapshot(*state, rc);
  return json_response(200, {{"tile", *n},
                             {"x", rc.x}, {"y", rc.y}, {"w", rc.w}, {"h", rc.h},
                             {"pass", state->passes},
                             {"mean", t.rgb},
                             {"std_error", t.stderr_rgb},
                             {"samples", t.samples}});
}

HttpResponse RequestHandler::job_image(const ApiRequest& req, const PathParams& p, bool exr) {
  const JobSnapshot s = visible_snapshot(req, p.at("id"), JobManager::SnapshotOf::state);
  const ImageSource& img = image_of(s);
  if ((exr && !config_.images.exr) || (!exr && !config_.images.png)) {
    throw HttpError(501, "image encoding is not available in this build");
  }
  const std::shared_ptr<const JobState> state = manager_.state(s);  // a finished job's: from the store
  if (!state) throw HttpError(409, "the job's state is not available");
  const ImageSnapshot snap = img.snapshot(*state);
  const json meta = {{"job_id", s.id},
                     {"state", std::string(job_status_name(s.status))},
                     {"samples", state->samples},
                     {"passes", state->passes},
                     {"spec", *s.spec}};
  HttpResponse r;
  r.set_header("Content-Type", exr ? "image/x-exr" : "image/png");
  r.set_header("Content-Disposition", fmt::format("inline; filename=\"{}.{}\"", s.id, exr ? "exr" : "png"));
  r.body = exr ? config_.images.exr(snap, meta) : config_.images.png(snap);
  return r;
}

}  // namespace tally
