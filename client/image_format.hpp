#pragma once
// The image file format an --image path asks for, by its extension: ".exr" (float RGB,
// standard errors and samples per pixel) or ".png" (an 8-bit preview), case-insensitive.
// Anything else is refused before any work is done (`tally run`, `tally get`).
#include <optional>
#include <string>

namespace tally {

enum class ImageFormat { exr, png };

std::optional<ImageFormat> image_format_of(const std::string& path);

// "cannot tell the image format of \"x.jpg\": use a .exr (float, with standard errors and
// samples per pixel) or .png (8-bit preview) file name".
std::string unknown_image_format_message(const std::string& path);

}  // namespace tally
