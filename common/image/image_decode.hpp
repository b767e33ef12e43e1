#pragma once
// Decoding image files held in memory (textures, environment maps) through the image
// module (libtally_image.so, image_module_abi.hpp; opened on first use like the
// encoders in image_io.hpp). No JSON here: the lighting engine includes this header.
// Thread-safe.
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace tally {

// The file's values as stored, without colour conversion: `channels` values a pixel,
// rows from the top. 8- and 16-bit files give integer codes in `codes` (0..255 or
// 0..65535, `bits` 8 or 16); float files (EXR, HDR) give `floats` (`bits` 32).
struct DecodedImage {
  int width = 0, height = 0, channels = 0, bits = 0;
  std::vector<uint16_t> codes;
  std::vector<float> floats;
  // What the decode was charged: ImageHeader::decode_bytes() + kept_bytes_per_pixel x pixels.
  uint64_t charged_bytes = 0;
};

// The format of an encoded file by its magic bytes: "png", "jpeg", "openexr", "hdr"
// (Radiance), or nullopt when it is none of these.
std::optional<std::string> sniff_image_format(std::string_view bytes);

// What one decode may take, checked against the file's header (image_header.hpp)
// before the image module sees the bytes.
struct ImageDecodeLimits {
  uint64_t max_pixels = 0;
  uint32_t max_channels = 8;
  // Bytes the decode may take: ImageHeader::decode_bytes() plus what the caller keeps
  // of each pixel after it (12 for a texture's texels), so the check covers the peak.
  uint64_t max_bytes = UINT64_MAX;
  uint64_t kept_bytes_per_pixel = 0;
};

// Decodes `bytes` (a file of a format sniff_image_format knows). Throws
// ImageModuleUnavailable (image_io.hpp) without the module, std::runtime_error when the
// file is not an image of that format, or is over a limit (checked from its header
// before its pixels are decoded; the message names the limit and the number).
DecodedImage decode_image(std::string_view bytes, const ImageDecodeLimits& limits);
inline DecodedImage decode_image(std::string_view bytes, uint64_t max_pixels) {
  return decode_image(bytes, ImageDecodeLimits{max_pixels});
}

}  // namespace tally
