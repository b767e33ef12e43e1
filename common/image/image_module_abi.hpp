#pragma once
// The C interface between the image loader (image_io.cpp, linked into every binary)
// and the image module (libtally_image.so, the only code that links OpenImageIO).
// The module is opened with dlopen on the first image read or written, so a binary
// that never touches an image never maps OpenImageIO and its ~250 dependencies.
// Plain C types only: no exceptions or C++ objects cross the boundary.
#include <cstddef>
#include <cstdint>

extern "C" {

// One rectangle of an image: RGB means and standard errors interleaved, row-major.
struct tally_image_view {
  int32_t x0, y0, width, height, full_width, full_height;
  const float* rgb;         // 3 * width * height
  const float* stderr_rgb;  // 3 * width * height
  const float* samples;     // width * height
};

// Receives output bytes (or an error message); may be called several times.
typedef void (*tally_image_sink)(void* context, const char* data, size_t size);

// Receives a decoded image: width x height pixels of 3 floats (R, G, B), row-major from
// the top row; called once.
typedef void (*tally_image_pixels_sink)(void* context, int32_t width, int32_t height, const float* rgb);

// Every function returns 0 on success; otherwise it has written a message to `error`.
struct tally_image_api {
  uint32_t abi_version;  // kTallyImageAbiVersion
  const char* backend;   // what it is built on, e.g. "OpenImageIO 2.4.7" or "OpenEXR 3.1.5 + libpng 1.6.39"
  // OpenEXR, 32-bit float channels R G B StdErr.R StdErr.G StdErr.B SampleCount;
  // `metadata_json` is a JSON object whose members become "tally:<key>" attributes.
  int (*encode_exr)(const tally_image_view* image, const char* metadata_json, tally_image_sink out,
                    void* out_context, tally_image_sink error, void* error_context);
  // 8-bit sRGB PNG of the means (already clamped and encoded by the caller: 3 bytes a pixel).
  int (*encode_png_rgb8)(int32_t width, int32_t height, const unsigned char* rgb8, tally_image_sink out,
                         void* out_context, tally_image_sink error, void* error_context);
  // Decodes the image in `data` (`format`: "exr" or "hdr", Radiance RGBE) to linear float
  // RGB as stored (no colour conversion): 1 or 2 channels -> grey in R, G and B; 3 or more
  // -> the first three (R, G, B; alpha ignored). The data window is the image. Refuses
  // images of more than `max_pixels` pixels before reading their pixels.
  int (*decode_rgb)(const char* data, size_t size, const char* format, uint64_t max_pixels,
                    tally_image_pixels_sink out, void* out_context, tally_image_sink error, void* error_context);
};

// The module's one exported symbol.
const tally_image_api* tally_image_module_api(void);

}  // extern "C"

namespace tally {
inline constexpr uint32_t kTallyImageAbiVersion = 2;  // 2: decode_rgb
inline constexpr const char* kTallyImageModuleSymbol = "tally_image_module_api";
}  // namespace tally
