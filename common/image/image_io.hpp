#pragma once
// Image files out of an ImageSnapshot: OpenEXR with the estimate, its standard error and
// the sample count per pixel (what a user needs to judge every pixel), and a tone-mapped
// 8-bit PNG preview. Used by the server's image routes and the CLI.
//
// The encoders live in the image module, libtally_image.so (image_module.cpp, the only
// code linking OpenImageIO). It is opened with dlopen on the first call here, so
// binaries that never read or write an image never map OpenImageIO. It is looked for at
// $TALLY_IMAGE_MODULE (only there, when set), next to the binary, in <binary dir>/../lib/tally,
// in the install lib dir and in the build tree. Thread-safe: the first call loads it once.
#include <filesystem>
#include <nlohmann/json.hpp>
#include <stdexcept>
#include <string>

#include "common/engine/image_source.hpp"

namespace tally {

// The image module could not be found or loaded; what() says where it was looked for.
class ImageModuleUnavailable : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// Half-float would lose the standard errors of dim pixels: every channel is 32-bit float.
// Channels: R, G, B, StdErr.R, StdErr.G, StdErr.B (standard error of the mean),
// SampleCount (float, so readers do not rescale it). Every member of `metadata` becomes
// an EXR header attribute "tally:<key>" (numbers as double, strings as strings,
// anything else as its JSON text). The snapshot's position in the full image is kept as
// the data window. Throws ImageModuleUnavailable, or std::runtime_error when OpenImageIO fails.
std::string encode_exr(const ImageSnapshot& image, const nlohmann::json& metadata);

// The EXR encode_exr makes of `source`'s whole image of `state`, written to `path` a
// strip of `strip_rows` rows at a time (ImageSource::snapshot of the strip): it holds
// one strip, never a snapshot of the whole image (a 3840x2160 one is 232 MB) nor its
// encoding. Written to `path` + ".part", renamed to `path` once complete. Throws like
// encode_exr.
void write_exr_file(const ImageSource& source, const JobState& state, const nlohmann::json& metadata,
                    const std::filesystem::path& path, int strip_rows = 32);

// 8-bit sRGB preview: each channel clamped to [0, 1], then the sRGB OETF, rounded.
std::string encode_png(const ImageSnapshot& image);

// The sRGB OETF of a linear value in [0, 1] (exposed for tests).
double srgb_oetf(double linear);

// Writes the EXR to `exr_path` and the PNG to `png_path`; an empty path skips that file.
// Throws std::runtime_error naming the path on failure.
void write_image_files(const ImageSnapshot& image, const nlohmann::json& metadata,
                       const std::filesystem::path& exr_path,
                       const std::filesystem::path& png_path);

// Path of the loaded image module, and what it is built on ("OpenImageIO 2.4.7", "OpenEXR
// 3.1.5 + libpng 1.6.39"). Both load it; both throw ImageModuleUnavailable.
std::string image_module_path();
std::string image_module_backend();
// Loads the image module now, on the calling thread, if no call has yet: a program that
// will write an image calls it on a thread of its own while it computes (the OpenImageIO
// module brings ~260 shared libraries, ~0.25 s to load). Never throws: a module that is
// unavailable is reported by the first image call, as without it.
void preload_image_module();

}  // namespace tally
