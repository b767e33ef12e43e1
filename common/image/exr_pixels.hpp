#pragma once
// The EXR's pixel layout, shared by the loader (image_io.cpp, write_exr_file's strips)
// and both image modules (encode_exr): 7 floats a pixel, R G B StdErr.R StdErr.G
// StdErr.B SampleCount, from an ImageSnapshot's planes.
#include <cstddef>

namespace tally {

inline void interleave_exr_pixels(const float* rgb, const float* stderr_rgb, const float* samples, size_t pixels,
                                  float* out) {
  for (size_t i = 0; i < pixels; ++i) {
    float* px = out + 7 * i;
    for (size_t c = 0; c < 3; ++c) {
      px[c] = rgb[3 * i + c];
      px[3 + c] = stderr_rgb[3 * i + c];
    }
    px[6] = samples[i];
  }
}

}  // namespace tally
