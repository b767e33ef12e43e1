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

// A decoded image as the file stores it (no colour conversion): `channels` values a
// pixel, rows from the top, `bits` 8 or 16 (unsigned integers, uint8_t / uint16_t) or 32
// (float). Valid only during the call of the receiver.
struct tally_decoded_image {
  int32_t width, height, channels, bits;
  const void* pixels;
};
typedef void (*tally_image_receiver)(void* context, const tally_decoded_image* image);

// Fills `rows` rows of an image from row `y` (0: the top of the data window) into `px`:
// 7 floats a pixel (R G B StdErr.R StdErr.G StdErr.B SampleCount), interleaved, row-major.
// Returns 0, or non-zero to stop the write (the caller keeps its reason).
typedef int (*tally_image_rows)(void* context, int32_t y, int32_t rows, float* px);

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
  // Decodes an encoded file held in memory (PNG, JPEG, ...; `format` names it: "png",
  // "jpeg", "openexr", "hdr"). Refuses images of more than `max_pixels` pixels before
  // decoding their pixels. Calls `receive` once on success.
  int (*decode)(const unsigned char* bytes, size_t size, const char* format, uint64_t max_pixels,
                tally_image_receiver receive, void* receive_context, tally_image_sink error, void* error_context);
  // The EXR encode_exr makes of `window` (its geometry; the pixel pointers are unused),
  // written to the file `path` with its pixels fetched from `rows` a strip of `strip_rows`
  // rows at a time: the module holds one strip, never the whole image. (ABI 3)
  int (*write_exr_file)(const tally_image_view* window, const char* metadata_json, const char* path,
                        int32_t strip_rows, tally_image_rows rows, void* rows_context, tally_image_sink error,
                        void* error_context);
};

// The module's one exported symbol.
const tally_image_api* tally_image_module_api(void);

}  // extern "C"

namespace tally {
inline constexpr uint32_t kTallyImageAbiVersion = 3;  // 2: decode; 3: write_exr_file
inline constexpr const char* kTallyImageModuleSymbol = "tally_image_module_api";
}  // namespace tally
