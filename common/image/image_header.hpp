#pragma once
// The header of an image file held in memory (PNG, JPEG, OpenEXR, Radiance HDR), read by
// hand before any image library sees the bytes: size, channels and sample size, so that
// a file is refused by the limits (image_decode.hpp) before its pixels are decoded. The
// readers only walk the header's own structure and check every length against the bytes
// that are there: an OpenEXR attribute that declares more bytes than the file holds
// (which OpenEXR would allocate before noticing) is refused here.
#include <cstdint>
#include <string>
#include <string_view>

namespace tally {

struct ImageHeader {
  std::string format;  // "png", "jpeg", "openexr", "hdr" (as sniff_image_format)
  uint64_t width = 0, height = 0;
  uint32_t channels = 0;
  uint32_t sample_bytes = 0;  // bytes of one stored sample: 1 or 2 (PNG, JPEG), 2 or 4 (EXR), 4 (HDR)

  uint64_t pixels() const { return width * height; }
  // Bytes decoding takes at its peak: the image module's buffer and the copy handed back
  // (image_decode.hpp: 8- and 16-bit files as 16-bit codes, others as floats), both held
  // for a moment. Saturates instead of overflowing.
  uint64_t decode_bytes() const;
};

// Throws std::runtime_error saying what is wrong when the header is not one of these
// formats, is truncated or inconsistent, or uses a feature the decoders refuse
// (multi-part or deep OpenEXR).
ImageHeader read_image_header(std::string_view bytes);

}  // namespace tally
