#include "client/image_format.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <filesystem>

namespace tally {

std::optional<ImageFormat> image_format_of(const std::string& path) {
  std::string ext = std::filesystem::path(path).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  if (ext == ".exr") return ImageFormat::exr;
  if (ext == ".png") return ImageFormat::png;
  return std::nullopt;
}

std::string unknown_image_format_message(const std::string& path) {
  return fmt::format(
      "cannot tell the image format of \"{}\": use a .exr (float, with standard errors and samples per pixel) or "
      ".png (8-bit preview) file name",
      path);
}

}  // namespace tally
