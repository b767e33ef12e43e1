// The image routes: GET /v1/jobs/{id}/tiles/{n}, image.exr, image.png. They read
// the immutable state of a JobSnapshot (a finished job's is read back from the
// store, JobManager::state), so encoding never holds a job's lock.
#include <fmt/format.h>
#include <unistd.h>

#include <atomic>
#include <filesystem>

#include "common/protocol/job_json.hpp"
#include "server/api/request_handler.hpp"
#include "server/api/route_support.hpp"
#include "server/http/file_body_stream.hpp"

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
  if ((exr && !config_.images.exr_file) || (!exr && !config_.images.png)) {
    throw HttpError(501, "image encoding is not available in this build");
  }
  const std::shared_ptr<const JobState> state = manager_.state(s);  // a finished job's: from the store
  if (!state) throw HttpError(409, "the job's state is not available");
  HttpResponse r;
  r.set_header("Content-Type", exr ? "image/x-exr" : "image/png");
  r.set_header("Content-Disposition", fmt::format("inline; filename=\"{}.{}\"", s.id, exr ? "exr" : "png"));
  if (!exr) {
    r.body = config_.images.png(img.snapshot(*state));
    return r;
  }
  // The EXR goes through a file, a strip of rows at a time, and is sent from it in parts:
  // a 4K frame's image (232 MB of floats) and its encoding (over 100 MB) are never in
  // memory whole. The stream unlinks the file as it opens it.
  const json meta = {{"job_id", s.id},
                     {"state", std::string(job_status_name(s.status))},
                     {"samples", state->samples},
                     {"passes", state->passes},
                     {"spec", *s.spec}};
  static std::atomic<uint64_t> serial{0};
  const std::filesystem::path path = std::filesystem::temp_directory_path() /
                                     fmt::format("tally-{}-{}-{}.exr", ::getpid(), s.id, serial.fetch_add(1));
  try {
    config_.images.exr_file(img, *state, meta, path);
    r.stream = std::make_shared<FileBodyStream>(path);  // unlinks it
  } catch (...) {
    std::error_code ignored;
    std::filesystem::remove(path, ignored);  // written but not opened: not left in the temp dir
    throw;
  }
  return r;
}

}  // namespace tally
