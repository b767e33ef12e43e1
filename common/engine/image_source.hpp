#pragma once
// Jobs that produce an image expose it through this interface, so the server
// (image routes, tile events), the CLI (--image) and the preview client need not
// know how the pixels were estimated. Pixel (x, y), row-major, y = 0 at the top.
#include <cstdint>
#include <vector>

#include "common/engine/job_state.hpp"

namespace tally {

struct TileRect {
  int x = 0, y = 0, w = 0, h = 0;
};

// A copy of (part of) the image: interleaved RGB means and standard errors of the
// mean, and a float sample count per pixel (float, so EXR readers don't rescale it).
struct ImageSnapshot {
  int x0 = 0, y0 = 0;  // position of this rectangle in the full image
  int width = 0, height = 0;
  int full_width = 0, full_height = 0;
  std::vector<float> rgb;         // 3 * width * height
  std::vector<float> stderr_rgb;  // 3 * width * height
  std::vector<float> samples;     // width * height
};

class ImageSource {
 public:
  virtual ~ImageSource() = default;
  virtual int width() const = 0;
  virtual int height() const = 0;
  virtual uint32_t tile_count() const = 0;
  virtual TileRect tile_rect(uint32_t tile) const = 0;
  // Tile that partition p of the kernel refines (partitions are tiles for images).
  virtual uint32_t tile_of_partition(uint32_t partition) const { return partition; }
  virtual ImageSnapshot snapshot(const JobState& state, const TileRect& rect) const = 0;
  ImageSnapshot snapshot(const JobState& state) const {
    return snapshot(state, TileRect{0, 0, width(), height()});
  }
};

}  // namespace tally
